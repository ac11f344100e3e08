"""How often a login may fail from one network address before it must wait: a budget of failures.

Each key (an address, or a name at an address) has a budget of `burst` failures that refills at
`per_s` a second; while it is spent, attempts under that key are refused before any password is
looked at. No key spans two addresses: wrong passwords from one address never make a right
login from another wait. A success takes nothing and gives nothing back: an attacker who also
knows one good login cannot clear the failures of its guesses with it. Pure but for a lock (the
dashboard answers each request in a thread of its own); the clock comes in.
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

    def __len__(self) -> int:
        """How many keys it remembers (at most `max_keys`)."""
        with self._lock:
            return len(self._spent)

    def _now_spent(self, key: str) -> float:
        entry = self._spent.get(key)
        if entry is None:
            return 0.0
        spent, at = entry
        return max(0.0, spent - (self.clock() - at) * self.per_s)


class LoginThrottle:
    """Failed logins counted per address and per (name, address): either one spent makes it wait.

    Nothing is counted per name alone: names are no secret, and a name-wide budget let anyone on
    the network keep the operator or the coordinator off (issue 51). Per address bounds the
    passwords one source has checked; per (name, address), smaller and slower to refill, keeps
    a client retrying a stale password from spending its whole address (where every component
    of `gridfleet up` comes from too). A flood from one address makes only that address wait;
    clients already connected are not touched. The defaults are the embedded broker's.
    """

    def __init__(
        self,
        *,
        pair_burst: int = 10,
        pair_per_s: float = 0.2,
        address_burst: int = 20,
        address_per_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        max_keys: int = 10_000,
    ) -> None:
        self.pairs = FailureBudget(pair_burst, pair_per_s, clock, max_keys)
        self.addresses = FailureBudget(address_burst, address_per_s, clock, max_keys)

    def wait_s(self, name: str | None, address: str) -> float:
        """Seconds this attempt from `address` must wait (0: check its password)."""
        by_pair = self.pairs.wait_s(_pair(name, address)) if name else 0.0
        return max(by_pair, self.addresses.wait_s(address))

    def failed(self, name: str | None, address: str, known_name: bool) -> None:
        """Count a failed attempt (pairs only for names that exist: made-up ones take no memory)."""
        if name and known_name:
            self.pairs.failed(_pair(name, address))
        self.addresses.failed(address)


def _pair(name: str, address: str) -> str:
    """One key for `name` at `address`: an address holds no NUL, so no two pairs share a key."""
    return f"{address}\0{name}"
