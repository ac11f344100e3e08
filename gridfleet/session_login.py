"""A page session's own broker password, and the sessions taken back at logout (pure: no I/O,
the time comes in).

The dashboard hands the page `gf1.<sid>.<expires>.<mac>` instead of the account's password:
`sid` the page session's id, `expires` its end (unix seconds), `mac` HMAC-SHA256 keyed by the
account's password over `name|sid|expires` (base64url, no padding). The embedded broker, which
reads the same accounts file, checks it without asking anybody, and refuses it once it has
expired or the dashboard has revoked its sid at logout (protocol.md §10). A copy of what the page
was handed then opens nothing after logout, and the account's password never reaches the page.
"""

from __future__ import annotations

import base64
import hashlib
import heapq
import hmac
import re
from dataclasses import dataclass

PREFIX = "gf1"
# A session id as the dashboard makes them (secrets.token_urlsafe): base64url, bounded.
SID_PATTERN = r"[A-Za-z0-9_-]{1,64}"
_SID_RE = re.compile(SID_PATTERN)
_PASSWORD_RE = re.compile(rf"{PREFIX}\.({SID_PATTERN})\.([0-9]{{1,12}})\.([A-Za-z0-9_-]{{43}})")
# Revocations one broker keeps at most (each costs ~150 bytes); past that, the soonest to
# expire goes first. Only dashboard accounts revoke, one per logout: far more than a fleet makes.
MAX_REVOKED = 100_000


@dataclass(frozen=True)
class SessionClaim:
    """What a session password says of itself: its session's id, its end, and its MAC."""

    sid: str
    expires: int  # unix seconds
    mac: str


def _mac(name: str, account_password: str, sid: str, expires: int) -> str:
    """The base64url HMAC-SHA256 of `name|sid|expires`, keyed by the account's password."""
    message = f"{name}|{sid}|{expires}".encode()
    digest = hmac.new(account_password.encode(), message, hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def make_session_password(name: str, account_password: str, sid: str, expires: int) -> str:
    """The broker password of session `sid` of account `name`, valid until `expires`."""
    if not _SID_RE.fullmatch(sid):
        raise ValueError(f"session id {sid!r} is not base64url of 1-64 characters")
    if expires < 0:
        raise ValueError(f"a session's end {expires} is before 1970")
    return f"{PREFIX}.{sid}.{expires}.{_mac(name, account_password, sid, expires)}"


def read_session_password(password: str | None) -> SessionClaim | None:
    """The claim of a password shaped as a session password (None: it is not one; unchecked)."""
    found = _PASSWORD_RE.fullmatch(password or "")
    if found is None:
        return None
    return SessionClaim(found.group(1), int(found.group(2)), found.group(3))


def is_session_password(password: str | None) -> bool:
    """Whether `password` is meant as a session password (starts `gf1.`), well made or not."""
    return (password or "").startswith(f"{PREFIX}.")


def session_password_refusal(
    name: str,
    account_password: str,
    password: str | None,
    now: float,
    revoked: RevokedSessions | None = None,
) -> str | None:
    """Why `password` does not log `name` in as one of its sessions (None: it does)."""
    claim = read_session_password(password)
    if claim is None:
        return "not a session password"
    expected = _mac(name, account_password, claim.sid, claim.expires)
    if not hmac.compare_digest(claim.mac.encode(), expected.encode()):
        return "a session password not made for this account"
    if now >= claim.expires:
        return "a session password that has expired"
    if revoked is not None and revoked.is_revoked(claim.sid, now):
        return "a session password taken back at logout"
    return None


class RevokedSessions:
    """Session ids taken back before their end; each is forgotten once it has expired anyway.

    A revoked session's password could not log in after its end either, so the set stays as
    small as the sessions logged out and not yet ended (at most `limit`; past that, the one
    that expires soonest goes first).
    """

    def __init__(self, limit: int = MAX_REVOKED) -> None:
        self.limit = limit
        self._ends: dict[str, int] = {}  # sid: its end (unix seconds)
        self._by_end: list[tuple[int, str]] = []  # heap, soonest end first (stale ones skipped)

    def __len__(self) -> int:
        return len(self._ends)

    def revoke(self, sid: str, expires: int, now: float) -> bool:
        """Take `sid` back until `expires`; False when there is nothing to keep (it has ended)."""
        self._prune(now)
        if now >= expires:
            return False
        if expires <= self._ends.get(sid, -1):
            return True  # already, as long or longer
        self._ends[sid] = expires
        heapq.heappush(self._by_end, (expires, sid))
        while len(self._ends) > self.limit:
            self._pop()
        return True

    def is_revoked(self, sid: str, now: float) -> bool:
        """Whether session `sid` was taken back and has not ended yet."""
        end = self._ends.get(sid)
        return end is not None and now < end

    def live(self, now: float) -> dict[str, int]:
        """The sessions taken back that have not ended yet, with their ends."""
        self._prune(now)
        return dict(self._ends)

    def _prune(self, now: float) -> None:
        """Forget the revocations of sessions that have ended."""
        while self._by_end and self._by_end[0][0] <= now:
            self._pop()

    def _pop(self) -> None:
        """Forget the revocation that ends soonest (a heap entry a later revoke replaced: skip)."""
        end, sid = heapq.heappop(self._by_end)
        if self._ends.get(sid) == end:
            del self._ends[sid]
