"""An accounts file kept current: re-read when it changes, so a revoked API token stops at the
next request, without a restart.

Each `current()` costs one `stat`: the file is read again only when its inode, size, mtime or
ctime changed (`write_accounts` renames a new file over it: a new inode each time). A file that
became unreadable or invalid leaves the last good accounts in force and is logged once (per
change), never raised to the request that noticed it; the first read, at start, raises.
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path

from gridfleet.accounts import Accounts, load_accounts
from gridfleet.errors import ConfigError

log = logging.getLogger("gridfleet.accounts")
Signature = tuple[int, int, int, int, int]  # device, inode, size, mtime_ns, ctime_ns


def signature(path: Path) -> Signature | None:
    """What changes when the file at `path` does (None: it cannot be looked at)."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


class AccountsFile:
    """An accounts file and the accounts it held when last read well.

    ConfigError at construction when it cannot be read (a start must fail loudly); after that,
    never. Thread-safe: the dashboard answers each request in a thread of its own.
    """

    def __init__(self, path: str | Path, load: Callable[[Path], Accounts] = load_accounts) -> None:
        self.path = Path(path)
        self._load = load
        self._lock = threading.Lock()
        self._seen = signature(self.path)  # taken before the read: a change during it is seen
        self._accounts = load(self.path)
        self._problem: str | None = None

    def current(self) -> Accounts:
        """The accounts now: re-read if the file changed since, else the ones read last."""
        with self._lock:
            seen = signature(self.path)
            if seen is not None and seen == self._seen:
                return self._accounts
            self._seen = seen
            try:
                if seen is None:
                    raise ConfigError(f"{self.path}: the accounts file is gone or cannot be read")
                accounts = self._load(self.path)
            except (ConfigError, OSError) as exc:  # OSError: gone between the read and a stat
                if str(exc) != self._problem:
                    log.error("%s; the accounts read before stay in force", exc)
                self._problem = str(exc)
                return self._accounts
            if self._problem is not None:
                log.warning("%s: the accounts file is good again", self.path)
            else:
                log.info("%s: re-read the accounts file (it changed)", self.path)
            self._problem = None
            self._accounts = accounts
            return accounts

    @property
    def problem(self) -> str | None:
        """What is wrong with the file since the last good read (None: nothing)."""
        with self._lock:
            return self._problem
