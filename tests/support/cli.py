"""Running `gridfleet` as a person does: a process of its own, its output as text.

A test run starts hundreds of short commands, and on the 2-core CI machine a bare interpreter's
imports cost each of them more CPU than its work. So each test process keeps a fork server: an
interpreter that has imported, once, what the commands import, and forks a process per command.
That process is still one of its own: the caller's environment and folder, `gridfleet` as its
name, stdin empty, its own stdout and stderr, its exit code (a signal's as -N), and the normal end
of an interpreter (exit handlers, threads joined); nothing of the test's process is shared with it.
A command asked for while the server runs another (two threads of a test) gets a bare one.
"""

from __future__ import annotations

import importlib
import json
import os
import select
import signal
import subprocess
import sys
import tempfile
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

# What `gridfleet`'s entry point and its short commands import, whichever runs.
PRELOAD = (
    "gridfleet.system.cli",
    "gridfleet.console.job",
    "gridfleet.console.status",
    "gridfleet.system.accounts_cli",
)
SUPPORT = Path(__file__).resolve().parent.parent  # tests/, where `support` is found


def gridfleet(
    *args: str,
    timeout: float = 60,
    cwd: Path | None = None,
    env: Mapping[str, str] | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run `gridfleet ARGS` in a process of its own; its exit code is the caller's to check.

    In `cwd` (else this process's folder), with `env` (else this process's environment).
    """
    command = ["gridfleet", *args]
    request = {
        "args": list(args),
        "env": dict(os.environ if env is None else env),
        "cwd": str(cwd or Path.cwd()),
    }
    if not _SERVER.lock.acquire(blocking=False):
        return _bare(command, request, timeout)
    try:
        with tempfile.TemporaryDirectory(prefix="gridfleet-cli-") as folder:
            out, err = Path(folder, "stdout"), Path(folder, "stderr")
            code = _SERVER.run({**request, "out": str(out), "err": str(err)}, timeout)
            if code is None:
                raise subprocess.TimeoutExpired(
                    command, timeout, out.read_bytes(), err.read_bytes()
                )
            return subprocess.CompletedProcess(command, code, out.read_text(), err.read_text())
    finally:
        _SERVER.lock.release()


def _bare(
    command: list[str], request: dict[str, Any], timeout: float
) -> subprocess.CompletedProcess[str]:
    """The command in a fresh interpreter, as `python -m gridfleet`."""
    done = subprocess.run(
        [sys.executable, "-m", "gridfleet", *request["args"]],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
        cwd=request["cwd"],
        env=request["env"],
        stdin=subprocess.DEVNULL,
    )
    return subprocess.CompletedProcess(command, done.returncode, done.stdout, done.stderr)


class _Server:
    """This process's fork server, started on first use; one command at a time."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.process: subprocess.Popen[bytes] | None = None

    def run(self, request: dict[str, Any], timeout: float) -> int | None:
        """The command's exit code; None when it ran past `timeout` (it is killed)."""
        server = self._running()
        assert server.stdin is not None and server.stdout is not None
        server.stdin.write(json.dumps(request).encode() + b"\n")
        server.stdin.flush()
        pid = int(_line(server.stdout, 30))
        try:
            return int(_line(server.stdout, timeout))
        except TimeoutError:
            os.kill(pid, signal.SIGKILL)
            _line(server.stdout, 30)  # reaped
            return None

    def _running(self) -> subprocess.Popen[bytes]:
        if self.process is None or self.process.poll() is not None:
            self.process = subprocess.Popen(
                [sys.executable, "-c", f"from support.cli import serve; serve({PRELOAD!r})"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                bufsize=0,  # unbuffered: a line read leaves the next one for `select` to see
                env={**os.environ, "PYTHONPATH": os.pathsep.join([str(SUPPORT), *sys.path])},
            )
        return self.process


def _line(stream: IO[bytes], timeout: float) -> str:
    """The server's next line, waiting at most `timeout`."""
    ready, _, _ = select.select([stream], [], [], timeout)
    if not ready:
        raise TimeoutError
    line = stream.readline()
    if not line:
        raise RuntimeError("the gridfleet fork server ended")
    return line.decode().strip()


_SERVER = _Server()


def serve(preload: Sequence[str]) -> None:
    """The fork server's loop: a request per line on stdin; the pid, then the exit code, on stdout."""
    for name in preload:
        importlib.import_module(name)
    requests, replies = sys.stdin.buffer, sys.stdout.buffer
    for line in requests:
        request = json.loads(line)
        pid = os.fork()
        if pid == 0:
            _become(request)  # raises SystemExit: the interpreter ends as a command's does
        replies.write(f"{pid}\n".encode())
        replies.flush()
        _, status = os.waitpid(pid, 0)
        replies.write(f"{os.waitstatus_to_exitcode(status)}\n".encode())
        replies.flush()


def _become(request: dict[str, Any]) -> None:
    """In the forked process: become `gridfleet ARGS`, stdin empty, output to the files given."""
    for fd, path, flags in (
        (0, os.devnull, os.O_RDONLY),
        (1, request["out"], os.O_WRONLY | os.O_CREAT),
        (2, request["err"], os.O_WRONLY | os.O_CREAT),
    ):
        file = os.open(path, flags, 0o600)
        os.dup2(file, fd)
        os.close(file)
    os.environ.clear()
    os.environ.update(request["env"])
    os.chdir(request["cwd"])
    sys.argv = ["gridfleet", *request["args"]]
    from gridfleet.system.cli import main

    sys.exit(main(request["args"]))
