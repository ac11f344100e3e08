"""A child process's output, read in a thread so tests can wait for a line; whether a pid lives."""

from __future__ import annotations

import os
import re
import subprocess
import threading

from support.wait import wait_for


def alive(pid: int) -> bool:
    """Whether process `pid` still exists."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


class Output:
    """Collects a process's output lines in a thread, so tests can wait for a line."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: list[str] = []
        assert proc.stdout is not None
        stream = proc.stdout
        self._thread = threading.Thread(
            target=lambda: self.lines.extend(iter(stream.readline, "")), daemon=True
        )
        self._thread.start()

    def wait(self, pattern: str, timeout: float = 60) -> re.Match[str]:
        """The first line matching `pattern` (waits for it)."""
        regex = re.compile(pattern)
        return wait_for(
            lambda: next((m for m in map(regex.search, list(self.lines)) if m), None),
            timeout,
            what=f"output matching {pattern!r}",
        )

    def wait_closed(self, timeout: float = 10) -> None:
        """Wait until the process's output has ended and every line of it is read."""
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise TimeoutError(f"the output did not end within {timeout:g} s")

    @property
    def text(self) -> str:
        """Everything so far."""
        return "".join(self.lines)
