"""Each process of a deployed system bench: CPU over the measured window and peak memory."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import psutil


@dataclass(frozen=True)
class ProcessFigures:
    """One process of the run: what it is, its share of a core and its peak resident memory."""

    name: str
    pid: int
    cpu_pct: float  # of one core, over the measured window
    peak_rss_mb: float


def _worker(proc: psutil.Process) -> bool:
    """A process doing the work, not one of multiprocessing's helpers."""
    try:
        cmdline = " ".join(proc.cmdline())
    except psutil.Error:
        return False
    return "resource_tracker" not in cmdline and "forkserver" not in cmdline


def _peak_rss_mb(proc: psutil.Process) -> float:
    """VmHWM: the most resident memory the process ever had (Linux), else its current RSS."""
    try:
        with open(f"/proc/{proc.pid}/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return round(int(line.split()[1]) / 1024, 1)
        return round(float(proc.memory_info().rss) / 2**20, 1)
    except (OSError, psutil.Error):
        return 0.0


class ProcessWatch:
    """`start()` at the window's start, `finish()` at its end: figures for every process."""

    def __init__(self, roots: Callable[[], dict[str, int]]) -> None:
        # name -> pid of each component's process (this bench's own too), read afresh each time:
        # a component restarting, or workers still starting, at the window's start are found at
        # its end (a CI run listed no unit process at all).
        self.roots = roots
        self._procs: dict[str, psutil.Process] = {}
        self._cpu0: dict[str, float] = {}
        self._t0 = 0.0

    def _collect(self) -> None:
        for name, pid in self.roots().items():
            try:
                root = psutil.Process(pid)
            except psutil.Error:
                continue
            self._procs[name] = root
            if pid == os.getpid():
                continue  # the bench: its children are the components, each a root of its own
            children = sorted(root.children(recursive=True), key=lambda p: p.pid)
            prefix = "units" if name == "robots" else name  # the robots' workers
            for n, child in enumerate(c for c in children if _worker(c)):
                self._procs.setdefault(f"{prefix}-{n}", child)

    def start(self) -> None:
        """Note every process and its CPU time so far."""
        self._collect()
        self._t0 = time.monotonic()
        self._cpu0 = {n: _cpu_s(p) for n, p in self._procs.items()}

    def finish(self) -> list[ProcessFigures]:
        """CPU % over the window since `start()` and peak RSS, per process (one first seen now:
        its CPU time since it started)."""
        self._collect()
        elapsed = max(time.monotonic() - self._t0, 1e-9)
        out = []
        for name, proc in self._procs.items():
            # (a component restarted meanwhile is a new process: its CPU time since it started)
            cpu = _cpu_s(proc) - self._cpu0.get(name, 0.0)
            if cpu < 0:
                cpu = _cpu_s(proc)
            out.append(
                ProcessFigures(name, proc.pid, round(100 * cpu / elapsed, 1), _peak_rss_mb(proc))
            )
        return out


def _cpu_s(proc: psutil.Process) -> float:
    try:
        times = proc.cpu_times()
    except psutil.Error:
        return 0.0
    return float(times.user + times.system)
