"""How often a login name or a network address may fail before it must wait: a budget of failures.

Each key (a name, an address) has a budget of `burst` failures that refills at `per_s` a second;
while it is spent, attempts under that key are refused before any password is looked at. A
success takes nothing and gives nothing back: an attacker who also knows one good login cannot
clear the failures of its guesses with it. Pure but for a lock (the dashboard answers each
request in a thread of its own); the clock comes in.
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable


class FailureBudget:
    """Failures per key, as a token bucket; at most `max_keys` keys remembered (oldest first out)."""

    def __init__(
        self,
        burst: int,
        per_s: float,
        clock: Callable[[], float] = time.monotonic,
        max_keys: int = 10_000,
    ) -> None:
        if burst < 1 or per_s <= 0:
            raise ValueError(f"a failure budget needs burst >= 1 and per_s > 0 ({burst}, {per_s})")
        self.burst = burst
        self.per_s = per_s
        self.clock = clock
        self.max_keys = max_keys
        self._spent: OrderedDict[str, tuple[float, float]] = OrderedDict()  # key: (spent, at)
        self._lock = threading.Lock()

    def wait_s(self, key: str) -> float:
        """Seconds until `key` may try again (0: go ahead)."""
        with self._lock:
            spent = self._now_spent(key)
            return 0.0 if spent <= self.burst - 1 else (spent - (self.burst - 1)) / self.per_s

    def failed(self, key: str) -> None:
        """Spend one failure of `key`'s budget."""
        with self._lock:
            now = self.clock()
            self._spent[key] = (min(self._now_spent(key) + 1, float(self.burst)), now)
            self._spent.move_to_end(key)
            while len(self._spent) > self.max_keys:
                self._spent.popitem(last=False)

    def _now_spent(self, key: str) -> float:
        entry = self._spent.get(key)
        if entry is None:
            return 0.0
        spent, at = entry
        return max(0.0, spent - (self.clock() - at) * self.per_s)


class LoginThrottle:
    """Failed logins counted per name and per address: either one spent makes the attempt wait.

    Per address stops one source guessing; per name stops many sources guessing one account (a
    second address gains nothing). A flood on one name makes that name's new logins wait while it
    lasts: clients already connected are not touched.
    """

    def __init__(
        self,
        *,
        name_burst: int = 10,
        name_per_s: float = 1.0,
        address_burst: int = 5,
        address_per_s: float = 0.1,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.names = FailureBudget(name_burst, name_per_s, clock)
        self.addresses = FailureBudget(address_burst, address_per_s, clock)

    def wait_s(self, name: str | None, address: str) -> float:
        """Seconds this attempt must wait (0: check its password)."""
        by_name = self.names.wait_s(name) if name else 0.0
        return max(by_name, self.addresses.wait_s(address))

    def failed(self, name: str | None, address: str, known_name: bool) -> None:
        """Count a failed attempt (names only when they exist: made-up ones cannot fill memory)."""
        if name and known_name:
            self.names.failed(name)
        self.addresses.failed(address)
