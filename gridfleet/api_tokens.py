"""API tokens: what a script shows the dashboard's HTTP API instead of a password (pure).

A token's text is `gft1_<id>_<secret>`: `id` 8 lowercase hex digits (which token it is, shown by
`gridfleet accounts token NAME --list` and named by `--revoke ID`), `secret` 32 random bytes,
base64url without padding. The accounts file keeps, under the account holding it, only the id,
the SHA-256 of the whole text (hex) and when it was made: the text is shown once, when it is
made, and a copy of the file opens no API. A token is the dashboard's, not the broker's: the
broker never sees one (protocol.md §10).

Wrong tokens are throttled as the dashboard's wrong passwords are (`gridfleet.throttle`): per
address, and per token id at an address (ids the file holds only). `TokenCheck` is the whole
check of one request's Authorization header; the accounts come from a callable (an
`AccountsFile`'s `current`, which re-reads the file when it changes).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import re
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import TYPE_CHECKING, NamedTuple, Protocol

from gridfleet.errors import ConfigError
from gridfleet.throttle import LoginThrottle

if TYPE_CHECKING:
    from gridfleet.accounts import Account, Accounts

TOKEN_PREFIX = "gft1_"
TOKEN_ID_CHARS = 8
TOKEN_SECRET_BYTES = 32
TOKEN_SECRET_CHARS = 43  # base64url of 32 bytes, unpadded
TOKEN_CHARS = len(TOKEN_PREFIX) + TOKEN_ID_CHARS + 1 + TOKEN_SECRET_CHARS
TOKEN_ID = re.compile(r"[0-9a-f]{8}")
SHA256_HEX = re.compile(r"[0-9a-f]{64}")
_TOKEN = re.compile(r"gft1_([0-9a-f]{8})_[A-Za-z0-9_-]{43}")
# RFC 6750's b64token, the credentials of `Authorization: Bearer <b64token>`.
_B64TOKEN = re.compile(r"[A-Za-z0-9\-._~+/]+=*")
MAX_HEADER_CHARS = 4096  # an Authorization header longer than this is refused unread
# Compared against when no account holds the id: an unknown id costs what a known one does.
_NOBODY_SHA256 = "0" * 64


class TokenRandom(Protocol):
    """Where a token's randomness comes from (the `secrets` module; tests inject their own)."""

    def token_bytes(self, nbytes: int) -> bytes:
        """`nbytes` random bytes."""
        ...


@dataclass(frozen=True)
class TokenRecord:
    """What the accounts file keeps of one token: its id, the SHA-256 of its text, its birth."""

    id: str
    sha256: str  # hex, of the whole text `gft1_<id>_<secret>`
    created: datetime  # aware (UTC when read from the file)

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not TOKEN_ID.fullmatch(self.id):
            raise ConfigError(f"API token id {self.id!r} is not 8 lowercase hex digits")
        if not isinstance(self.sha256, str) or not SHA256_HEX.fullmatch(self.sha256):
            raise ConfigError(
                f"API token {self.id}: sha256 is not 64 lowercase hex digits (a SHA-256, in hex)"
            )
        if not isinstance(self.created, datetime) or self.created.utcoffset() is None:
            raise ConfigError(f"API token {self.id}: created {self.created!r} has no time zone")


class ParsedToken(NamedTuple):
    """A well-formed token's id and its whole text."""

    id: str
    text: str


@dataclass(frozen=True)
class MalformedHeader:
    """An Authorization header that is not `Bearer TOKEN`; `reason` says what it is instead."""

    reason: str


def token_sha256(text: str) -> str:
    """The hex SHA-256 the accounts file keeps of a token's text."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def created_text(created: datetime) -> str:
    """A token's creation time as the accounts file and `--list` write it (`…T07:40:00Z`)."""
    return created.astimezone(UTC).isoformat().replace("+00:00", "Z")


def parse_created(text: str) -> datetime:
    """A creation time from the file (ISO 8601 with a zone), in UTC; ConfigError otherwise."""
    try:
        when = datetime.fromisoformat(text)
        if when.utcoffset() is None:
            raise ValueError("no time zone")
        return when.astimezone(UTC)
    except (ValueError, OverflowError):
        raise ConfigError(
            f"created {text!r} is not a time with its zone, like 2026-12-02T07:40:00Z"
        ) from None


def new_token(
    rng: TokenRandom = secrets, created: datetime | None = None
) -> tuple[str, TokenRecord]:
    """A new token: its text (to show once) and the record the accounts file keeps of it.

    `created` defaults to now, in UTC, to the second.
    """
    token_id = rng.token_bytes(TOKEN_ID_CHARS // 2).hex()
    secret = _base64url(rng.token_bytes(TOKEN_SECRET_BYTES))
    text = f"{TOKEN_PREFIX}{token_id}_{secret}"
    when = created if created is not None else datetime.now(UTC).replace(microsecond=0)
    return text, TokenRecord(token_id, token_sha256(text), when)


def _base64url(data: bytes) -> str:
    """`data` in base64url without padding."""
    return base64.urlsafe_b64encode(data).rstrip(b"=").decode("ascii")


def parse_token(text: object) -> ParsedToken | None:
    """The id and text of a well-formed token (`gft1_<id>_<secret>`), else None; never raises."""
    if not isinstance(text, str) or len(text) != TOKEN_CHARS:
        return None
    match = _TOKEN.fullmatch(text)
    return None if match is None else ParsedToken(match.group(1), text)


def account_of_token(accounts: Accounts, text: object) -> Account | None:
    """The account holding token `text`, or None; never raises, whatever `text` is.

    Malformed text is refused before any lookup. The hashes are compared in constant time, and a
    well-formed token whose id nobody holds is compared too, so an unknown id costs what a known
    one does.
    """
    parsed = parse_token(text)
    if parsed is None:
        return None
    held = accounts.token_holder(parsed.id)
    expected = held[1].sha256 if held is not None else _NOBODY_SHA256
    same = hmac.compare_digest(token_sha256(parsed.text), expected)
    return held[0] if held is not None and same else None


def bearer_token(header_value: object) -> str | MalformedHeader | None:
    """The credentials of an Authorization header: None when there is no header, the token's
    text for `Bearer TOKEN` (the scheme in any case), MalformedHeader for anything else (`Basic
    …`, `Bearer` and nothing, spaces inside, over MAX_HEADER_CHARS). Never raises."""
    if header_value is None:
        return None
    if not isinstance(header_value, str):
        return MalformedHeader("the Authorization header is not text")
    if len(header_value) > MAX_HEADER_CHARS:
        return MalformedHeader(f"the Authorization header is over {MAX_HEADER_CHARS} characters")
    scheme, _, credentials = header_value.strip(" \t").partition(" ")
    if not scheme.isascii() or scheme.lower() != "bearer":
        # Not echoed: what was sent may be a password or a token without its scheme.
        return MalformedHeader(
            "the Authorization header is not Bearer: send 'Authorization: Bearer TOKEN'"
        )
    credentials = credentials.lstrip(" ")
    if not credentials:
        return MalformedHeader("the Authorization header says Bearer but no token")
    if not _B64TOKEN.fullmatch(credentials):
        return MalformedHeader(
            "the Authorization header's token is not one word of letters, digits and -._~+/"
        )
    return credentials


def issue_token(
    accounts: Accounts,
    name: str,
    rng: TokenRandom = secrets,
    created: datetime | None = None,
) -> tuple[str, TokenRecord, Accounts]:
    """A new token for account `name`: its text, its record, and the accounts holding it.

    ConfigError when there is no such account or its role holds no tokens. The id is drawn again
    while another token of the file has it.
    """
    from gridfleet.accounts import TOKEN_ROLES, TOKEN_ROLES_TEXT  # here: accounts imports us

    account = accounts.get(name)
    if account.role not in TOKEN_ROLES:
        raise ConfigError(
            f"account {name} is a {account.role} account: API tokens are for {TOKEN_ROLES_TEXT} "
            "accounts"
        )
    for _ in range(100):
        text, record = new_token(rng, created)
        if accounts.token_holder(record.id) is None:
            held = replace(account, tokens=(*account.tokens, record))
            return text, record, accounts.with_replaced(held)
    raise ConfigError("could not draw an API token id the file does not hold yet")


def revoke_tokens(
    accounts: Accounts, name: str, which: str
) -> tuple[tuple[TokenRecord, ...], Accounts]:
    """Account `name`'s token `which` (an id, a token's whole text, or `all`) taken away: the
    records, and the accounts without them.

    ConfigError when there is no such account, or it holds no token of that id (its ids named).
    `all` on an account without tokens takes nothing away.
    """
    account = accounts.get(name)
    if which == "all":
        gone = account.tokens
    else:
        parsed = parse_token(which)
        token_id = which if parsed is None else parsed.id
        gone = tuple(t for t in account.tokens if t.id == token_id)
        if not gone:
            held = ", ".join(t.id for t in account.tokens) or "none"
            shown = which if parsed is None else token_id  # never a whole token's text
            raise ConfigError(f"account {name} holds no API token {shown!r} (its tokens: {held})")
    kept = tuple(t for t in account.tokens if t not in gone)
    return gone, accounts.with_replaced(replace(account, tokens=kept))


# ---- one request's Authorization header, checked and throttled -------------------------------


@dataclass(frozen=True)
class TokenOk:
    """The header's token is `account`'s token `token_id`."""

    account: Account
    token_id: str


@dataclass(frozen=True)
class TokenMissing:
    """No Authorization header (the caller may look for a session instead)."""


@dataclass(frozen=True)
class TokenMalformed:
    """An Authorization header that is not `Bearer TOKEN`; nothing was counted."""

    reason: str


@dataclass(frozen=True)
class TokenWrong:
    """A Bearer token no account holds (counted as a failed login); `account_name`: the
    account holding a token of its id, if one does (for the audit, never for the client)."""

    reason: str
    token_id: str | None
    account_name: str | None


@dataclass(frozen=True)
class TokenThrottled:
    """Too many wrong tokens from this address (or of this id at it): wait `wait_s`."""

    wait_s: float
    token_id: str | None
    account_name: str | None

    @property
    def retry_after(self) -> int:
        """Whole seconds for a Retry-After header (at least 1)."""
        return max(1, round(self.wait_s))


TokenVerdict = TokenOk | TokenMissing | TokenMalformed | TokenWrong | TokenThrottled
WRONG_TOKEN = "wrong or revoked API token"


def token_throttle(clock: Callable[[], float] = time.monotonic) -> LoginThrottle:
    """A throttle with the dashboard login's budgets (docs/network.md): 5 wrong tokens of one id
    at an address (then one every 12 s), 10 from an address (then one every 6 s)."""
    return LoginThrottle(
        pair_burst=5, pair_per_s=1 / 12, address_burst=10, address_per_s=1 / 6, clock=clock
    )


def throttle_key(token_id: str) -> str:
    """The name a token id is counted under: never an account name (ids have no ':'), so one
    throttle may count passwords and tokens both."""
    return f"token:{token_id}"


class TokenCheck:
    """Checks a request's Authorization header against the accounts `accounts()` gives now.

    A wrong token spends the address's budget, and its id's at that address when an account
    holds that id; while either is spent, tokens from there are refused before any is looked at.
    A right token spends and gives back nothing (`gridfleet.throttle`). Thread-safe as the
    throttle is; never raises for any header.
    """

    def __init__(self, accounts: Callable[[], Accounts], throttle: LoginThrottle) -> None:
        self.accounts = accounts
        self.throttle = throttle

    def check(self, header_value: str | None, address: str) -> TokenVerdict:
        """The verdict on one request's Authorization header, sent from `address`."""
        got = bearer_token(header_value)
        if got is None:
            return TokenMissing()
        if isinstance(got, MalformedHeader):
            return TokenMalformed(got.reason)
        accounts = self.accounts()
        parsed = parse_token(got)
        token_id = None if parsed is None else parsed.id
        held = None if token_id is None else accounts.token_holder(token_id)
        holder = None if held is None else held[0].name
        key = None if token_id is None else throttle_key(token_id)
        wait = self.throttle.wait_s(key, address)
        if wait > 0:
            return TokenThrottled(wait, token_id, holder)
        account = account_of_token(accounts, got)
        if account is None or token_id is None:
            self.throttle.failed(key, address, known_name=held is not None)
            return TokenWrong(WRONG_TOKEN, token_id, holder)
        return TokenOk(account, token_id)
