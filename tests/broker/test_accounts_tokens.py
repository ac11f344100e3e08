"""API tokens in the accounts file: made, kept hashed, read back, refused when bad, listed and
revoked from the command line, picked up by a running reader, and wrong ones throttled."""

from __future__ import annotations

import base64
import hashlib
import logging
import random
import re
import stat
import subprocess
from dataclasses import replace
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gridfleet.accounts import (
    TOKEN_ROLES,
    Account,
    Accounts,
    default_accounts,
    dump_accounts,
    load_accounts,
    write_accounts,
)
from gridfleet.accounts_watch import AccountsFile
from gridfleet.api_tokens import (
    MAX_HEADER_CHARS,
    TOKEN_CHARS,
    MalformedHeader,
    ParsedToken,
    TokenCheck,
    TokenMalformed,
    TokenMissing,
    TokenOk,
    TokenRecord,
    TokenThrottled,
    TokenWrong,
    account_of_token,
    bearer_token,
    issue_token,
    new_token,
    parse_token,
    revoke_tokens,
    token_sha256,
    token_throttle,
)
from gridfleet.errors import ConfigError

from support.cli import gridfleet

TOKEN_FORM = re.compile(r"gft1_[0-9a-f]{8}_[A-Za-z0-9_-]{43}")
WHEN = datetime(2026, 12, 2, 7, 40, tzinfo=UTC)


class SeededRandom:
    """A token source that repeats itself: the same seed, the same tokens."""

    def __init__(self, seed: int) -> None:
        self.random = random.Random(seed)

    def token_bytes(self, nbytes: int) -> bytes:
        return self.random.randbytes(nbytes)


class Clock:
    """A clock the test moves."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def people() -> Accounts:
    """The default accounts and a viewer, `ann`."""
    accounts = default_accounts(["unit1"])
    return accounts.with_account(Account("ann", "a long enough password", "viewer"))


def with_tokens(accounts: Accounts, *names: str) -> tuple[Accounts, dict[str, str]]:
    """`accounts` with one new token for each of `names`; and each one's text."""
    texts = {}
    for name in names:
        texts[name], _, accounts = issue_token(accounts, name, created=WHEN)
    return accounts, texts


def private(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    path.chmod(0o600)
    return path


# ---- a token's text ---------------------------------------------------------------------------


def test_a_new_token_is_gft1_an_id_and_32_random_bytes_and_its_record_its_hash() -> None:
    text, record = new_token(SeededRandom(1), created=WHEN)
    assert TOKEN_FORM.fullmatch(text) and len(text) == TOKEN_CHARS
    assert text == new_token(SeededRandom(1), created=WHEN)[0]  # the randomness comes in
    assert text != new_token(SeededRandom(2), created=WHEN)[0]
    _, token_id, secret = text.split("_", 2)
    assert record == TokenRecord(token_id, hashlib.sha256(text.encode()).hexdigest(), WHEN)
    assert len(base64.urlsafe_b64decode(secret + "=")) == 32
    assert parse_token(text) == ParsedToken(token_id, text)
    made_now = new_token()[1].created  # by default: now, in UTC, to the second
    assert made_now.tzinfo is UTC and made_now.microsecond == 0
    assert abs(datetime.now(UTC) - made_now) < timedelta(minutes=1)
    assert len({new_token()[0] for _ in range(200)}) == 200


@pytest.mark.parametrize(
    "text",
    [
        "",
        "gft1_",
        "gft2_0123abcd_" + "A" * 43,
        "GFT1_0123abcd_" + "A" * 43,
        "gft1_0123ABCD_" + "A" * 43,  # the id is lowercase hex
        "gft1_0123abc_" + "A" * 44,
        "gft1_0123abcd_" + "A" * 42,
        "gft1_0123abcd_" + "A" * 44,
        "gft1_0123abcd_" + "A" * 42 + "=",
        "gft1_0123abcd_" + "A" * 42 + "+",  # base64url, not base64
        "gft1_0123abcd-" + "A" * 43,
        " gft1_0123abcd_" + "A" * 42,
        "gft1_0123abcd_" + "A" * 42 + "\n",
        "gft1_0123abcd_" + "A" * 41 + "é",
        "gft1_\u0660\u0661\u0662\u0663abcd_" + "A" * 43,  # Arabic-Indic digits are not hex
    ],
)
def test_malformed_token_text_is_refused_before_any_lookup(text: str) -> None:
    assert parse_token(text) is None
    assert account_of_token(people(), text) is None


def test_parse_token_refuses_what_is_not_text() -> None:
    for value in (None, 7, b"gft1_0123abcd_" + b"A" * 43, ["gft1"]):
        assert parse_token(value) is None
        assert account_of_token(people(), value) is None


def test_a_token_opens_its_account_and_nothing_else_does() -> None:
    accounts, texts = with_tokens(people(), "operator", "dashboard", "ann")
    for name, text in texts.items():
        found = account_of_token(accounts, text)
        assert found is not None and found.name == name
    text = texts["operator"]
    token_id = parse_token(text)
    assert token_id is not None
    flipped = text[:-1] + ("B" if text[-1] != "B" else "C")  # right id, wrong secret
    assert account_of_token(accounts, flipped) is None
    stranger = "gft1_" + ("00000000" if token_id.id != "00000000" else "11111111") + text[13:]
    assert account_of_token(accounts, stranger) is None  # an id nobody holds
    assert account_of_token(people(), text) is None  # a file without it


@pytest.mark.parametrize(
    ("header", "expected"),
    [
        (None, None),
        ("Bearer gft1_0123abcd_xyz", "gft1_0123abcd_xyz"),
        ("bearer abc", "abc"),
        ("BEARER   abc", "abc"),
        ("Bearer abc==", "abc=="),
        ("  Bearer abc  ", "abc"),
        ("Bearer abc.def~+/", "abc.def~+/"),
    ],
)
def test_a_bearer_header_gives_its_token_and_none_is_told_apart(
    header: str | None, expected: str | None
) -> None:
    assert bearer_token(header) == expected


@pytest.mark.parametrize(
    ("header", "says"),
    [
        ("", "not Bearer"),
        ("Basic b3BlcmF0b3I6cHc=", "not Bearer"),
        ("gft1_0123abcd_" + "A" * 43, "not Bearer"),
        ("Bearer", "no token"),
        ("Bearer ", "no token"),
        ("Bearertoken", "not Bearer"),
        ("Bearer a b", "not one word"),
        ("Bearer a\tb", "not one word"),
        ("Bearer ab=c", "not one word"),
        ("Bearer tökén", "not one word"),
        ("Bearer " + "A" * MAX_HEADER_CHARS, f"over {MAX_HEADER_CHARS}"),
        ("Token abc", "not Bearer"),
    ],
)
def test_a_malformed_authorization_header_is_told_from_a_missing_one(
    header: str, says: str
) -> None:
    got = bearer_token(header)
    assert isinstance(got, MalformedHeader) and says in got.reason
    assert "b3BlcmF0b3I6cHc" not in got.reason and "gft1" not in got.reason  # nothing echoed


# ---- in the accounts file ---------------------------------------------------------------------


def test_tokens_are_written_hashed_and_read_back_the_same(tmp_path: Path) -> None:
    accounts, texts = with_tokens(people(), "operator", "operator", "dashboard", "ann")
    assert len(accounts.get("operator").tokens) == 2
    path = tmp_path / "accounts.toml"
    write_accounts(accounts, path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert load_accounts(path) == accounts
    written = path.read_text(encoding="utf-8")
    for text in texts.values():
        assert text not in written and text.split("_", 2)[2] not in written  # only the hash
        assert token_sha256(text) in written
    assert 'created = "2026-12-02T07:40:00Z"' in written
    # A time in another zone, or to the microsecond, reads as the same instant and is kept.
    zoned = written.replace("2026-12-02T07:40:00Z", "2026-12-02T09:40:00.250000+02:00", 1)
    back = load_accounts(private(path, zoned))
    (moved,) = [t for a in back.accounts.values() for t in a.tokens if t.created != WHEN]
    assert moved.created == WHEN + timedelta(microseconds=250000)
    assert moved.created.tzinfo is UTC
    write_accounts(back, path)
    assert load_accounts(path) == back
    assert 'created = "2026-12-02T07:40:00.250000Z"' in path.read_text(encoding="utf-8")


def test_writing_replaces_the_file_whole_and_keeps_it_private(tmp_path: Path) -> None:
    path = tmp_path / "accounts.toml"
    path.write_text("old", encoding="utf-8")
    path.chmod(0o644)
    accounts = people()
    write_accounts(accounts, path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert load_accounts(path) == accounts
    assert [p.name for p in tmp_path.iterdir()] == ["accounts.toml"]  # no temporary left
    link = tmp_path / "link.toml"
    link.symlink_to(path)
    accounts, _ = with_tokens(accounts, "ann")
    write_accounts(accounts, link)
    assert link.is_symlink() and load_accounts(path) == accounts  # the link's target written


def test_writing_into_a_missing_folder_fails_and_leaves_nothing(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        write_accounts(people(), tmp_path / "no" / "accounts.toml")
    assert list(tmp_path.iterdir()) == []


GOOD_ID, GOOD_HASH = "0123abcd", "ab" * 32
PERSON = "[accounts.ann]\npassword = 'long enough pw'\nrole = 'operator'\n"


def token_line(
    token_id: str = GOOD_ID, sha256: str = GOOD_HASH, created: str = "'2026-12-02T07:40:00Z'"
) -> str:
    return f"tokens = [{{ id = '{token_id}', sha256 = '{sha256}', created = {created} }}]\n"


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        (PERSON + token_line(token_id="0123ABCD"), "account ann: token 1: API token id '0123ABCD'"),
        (PERSON + token_line(token_id="0123abc"), "is not 8 lowercase hex digits"),
        (PERSON + token_line(token_id="0123abcde"), "is not 8 lowercase hex digits"),
        (PERSON + token_line(sha256="ab" * 31), "account ann: token 1: API token 0123abcd: sha256"),
        (PERSON + token_line(sha256="AB" * 32), "sha256 is not 64 lowercase hex digits"),
        (PERSON + token_line(created="'yesterday'"), "account ann: token 1: created 'yesterday'"),
        (PERSON + token_line(created="'2026-12-02T07:40:00'"), "is not a time with its zone"),
        (PERSON + token_line(created="'2026-12-02'"), "is not a time with its zone"),
        (PERSON + token_line(created="'0001-01-01T00:00:00+01:00'"), "is not a time with its"),
        (PERSON + token_line(created="2026-12-02T07:40:00Z"), "tokens is a list of"),
        (PERSON + token_line(sha256="1' , extra = 'x"), "tokens is a list of"),
        (PERSON + "tokens = 'gft1_0123abcd'\n", "tokens is a list of"),
        (PERSON + "tokens = [{ id = '0123abcd' }]\n", "tokens is a list of"),
        (
            "[accounts.u1]\npassword = 'long enough pw'\nrole = 'unit'\nunit = 'u1'\n"
            + token_line(),
            "account u1: a unit account holds no API tokens (only operator, dashboard and viewer",
        ),
        (
            PERSON + "tokens = [{ id = '0123abcd', sha256 = '" + GOOD_HASH + "', created = "
            "'2026-12-02T07:40:00Z' }, { id = '0123abcd', sha256 = '" + "cd" * 32 + "', "
            "created = '2026-12-02T07:41:00Z' }]\n",
            "account ann: API token id '0123abcd' twice",
        ),
        (
            PERSON + token_line() + "[accounts.bob]\npassword = 'long enough pw'\n"
            "role = 'viewer'\n" + token_line(sha256="cd" * 32),
            "accounts ann and bob both hold API token id '0123abcd'",
        ),
    ],
)
def test_a_bad_token_in_the_file_is_refused_naming_the_file_and_account(
    tmp_path: Path, text: str, problem: str
) -> None:
    path = private(tmp_path / "accounts.toml", text)
    with pytest.raises(ConfigError, match=re.escape(problem)) as refused:
        load_accounts(path)
    assert str(refused.value).startswith(f"{path}: ")


def test_only_the_api_roles_hold_tokens_and_no_id_twice() -> None:
    record = TokenRecord(GOOD_ID, GOOD_HASH, WHEN)
    for role in TOKEN_ROLES:
        assert Account("p", "a long enough password", role, tokens=(record,)).tokens == (record,)
    with pytest.raises(ConfigError, match="a coordinator account holds no API tokens"):
        Account("c", "a long enough password", "coordinator", tokens=(record,))
    with pytest.raises(ConfigError, match="has no time zone"):
        TokenRecord(GOOD_ID, GOOD_HASH, datetime(2026, 12, 2, 7, 40))
    assert TokenRecord(GOOD_ID, GOOD_HASH, WHEN.astimezone(timezone(timedelta(hours=2)))) == (
        TokenRecord(GOOD_ID, GOOD_HASH, WHEN)
    )
    accounts, _ = with_tokens(people(), "ann")
    ann = accounts.get("ann")
    operator = replace(accounts.get("operator"), tokens=ann.tokens)
    with pytest.raises(ConfigError, match="accounts operator and ann both hold API token id"):
        accounts.with_replaced(operator)
    with pytest.raises(ConfigError, match="no account 'zed'"):
        accounts.with_replaced(replace(ann, name="zed"))


def test_issue_and_revoke_refuse_what_they_cannot_do() -> None:
    accounts = people()
    with pytest.raises(ConfigError, match="account unit1 is a unit account: API tokens are for"):
        issue_token(accounts, "unit1")
    with pytest.raises(ConfigError, match="no account 'zed'"):
        issue_token(accounts, "zed")
    with pytest.raises(ConfigError, match="no account 'zed'"):
        revoke_tokens(accounts, "zed", "all")
    accounts, texts = with_tokens(accounts, "ann", "ann")
    ids = [t.id for t in accounts.get("ann").tokens]
    with pytest.raises(ConfigError, match=f"account ann holds no API token 'ffffffff' .*{ids[0]}"):
        revoke_tokens(accounts, "ann", "ffffffff")
    with pytest.raises(ConfigError, match="account operator holds no API token") as wrong:
        revoke_tokens(accounts, "operator", texts["ann"])
    assert texts["ann"] not in str(wrong.value)  # a token's text is never shown back
    gone, fewer = revoke_tokens(accounts, "ann", texts["ann"])  # by its text, too
    assert [t.id for t in gone] == [texts["ann"][5:13]]
    assert account_of_token(fewer, texts["ann"]) is None
    gone, none = revoke_tokens(fewer, "ann", "all")
    assert len(gone) == 1 and none.get("ann").tokens == ()
    assert revoke_tokens(none, "ann", "all") == ((), none)


def test_an_id_another_token_holds_is_drawn_again() -> None:
    accounts, _ = with_tokens(people(), "ann")
    held = accounts.get("ann").tokens[0].id

    class Repeats:
        """Draws the held id once, then another."""

        def __init__(self) -> None:
            self.calls = 0

        def token_bytes(self, nbytes: int) -> bytes:
            self.calls += 1
            return bytes.fromhex(held) if self.calls == 1 else bytes([self.calls]) * nbytes

    _, record, more = issue_token(accounts, "operator", Repeats())
    assert record.id != held and more.token_holder(record.id) is not None


# ---- the command line ---------------------------------------------------------------------------


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return gridfleet(*args)


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_the_cli_prints_a_token_once_lists_and_revokes_it(tmp_path: Path) -> None:
    path = tmp_path / "accounts.toml"
    write_accounts(people(), path)
    made = cli("accounts", "token", "operator", "--file", str(path))
    assert made.returncode == 0, made.stderr
    text = made.stdout.strip()
    assert made.stdout == text + "\n" and TOKEN_FORM.fullmatch(text)  # the token, alone
    token_id = text[5:13]
    assert "shown this once" in made.stderr and f"--revoke {token_id}" in made.stderr
    assert text not in made.stderr
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    found = account_of_token(load_accounts(path), text)
    assert found is not None and found.name == "operator"
    second = cli("accounts", "token", "operator", "--file", str(path)).stdout.strip()
    listed = cli("accounts", "token", "operator", "--file", str(path), "--list")
    assert listed.returncode == 0, listed.stderr
    lines = listed.stdout.splitlines()
    assert [line.split()[0] for line in lines] == [token_id, second[5:13]]
    assert all(re.fullmatch(r"[0-9a-f]{8}  \d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", x) for x in lines)
    assert token_sha256(text) not in listed.stdout  # never the hashes
    revoked = cli("accounts", "token", "operator", "--file", str(path), "--revoke", token_id)
    assert revoked.returncode == 0 and token_id in revoked.stdout
    after = load_accounts(path)
    assert account_of_token(after, text) is None
    assert account_of_token(after, second) is not None  # the other stays
    every = cli("accounts", "token", "operator", "--file", str(path), "--revoke", "all")
    assert every.returncode == 0 and second[5:13] in every.stdout
    assert load_accounts(path).get("operator").tokens == ()
    empty = cli("accounts", "token", "operator", "--file", str(path), "--list")
    assert empty.returncode == 0 and empty.stdout == "" and "no API tokens" in empty.stderr
    viewer = cli("accounts", "token", "ann", "--file", str(path))
    assert viewer.returncode == 0, viewer.stderr
    assert account_of_token(load_accounts(path), viewer.stdout.strip()) is not None


@pytest.mark.slow  # a fleet, a CLI process or the API over a real broker: make test, not test-fast
def test_the_cli_refuses_in_words_and_changes_nothing(tmp_path: Path) -> None:
    path = tmp_path / "accounts.toml"
    accounts, _ = with_tokens(people(), "operator")
    write_accounts(accounts, path)
    before = path.read_bytes()
    token = ["accounts", "token"]
    for argv, says in [
        ([*token, "zed", "--file", str(path)], "no account 'zed'"),
        ([*token, "unit1", "--file", str(path)], "unit1 is a unit account: API tokens are for"),
        ([*token, "coordinator", "--file", str(path)], "a coordinator account"),
        ([*token, "zed", "--file", str(path), "--list"], "no account 'zed'"),
        ([*token, "operator", "--file", str(path), "--revoke", "ffffffff"], "no API token"),
        ([*token, "zed", "--file", str(path), "--revoke", "all"], "no account 'zed'"),
        ([*token, "operator", "--file", str(tmp_path / "none.toml")], "no such accounts file"),
        ([*token, "operator", "--file", str(path), "--list", "--revoke", "all"], "not allowed"),
    ]:
        bad = cli(*argv)
        assert bad.returncode == 2, (argv, bad.stderr)
        assert says in bad.stderr and "Traceback" not in bad.stderr and bad.stdout == ""
        assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["accounts.toml"]


# ---- a reader that follows the file -------------------------------------------------------------


def test_a_running_reader_sees_a_revocation_at_its_next_look(tmp_path: Path) -> None:
    path = tmp_path / "accounts.toml"
    accounts, texts = with_tokens(people(), "operator")
    write_accounts(accounts, path)
    loads: list[Path] = []

    def counted(p: Path) -> Accounts:
        loads.append(p)
        return load_accounts(p)

    watched = AccountsFile(path, load=counted)
    assert account_of_token(watched.current(), texts["operator"]) is not None
    assert watched.current() is watched.current() and len(loads) == 1  # unchanged: not read
    done = cli("accounts", "token", "operator", "--file", str(path), "--revoke", "all")
    assert done.returncode == 0, done.stderr
    assert account_of_token(watched.current(), texts["operator"]) is None
    assert len(loads) == 2 and watched.problem is None
    made = cli("accounts", "token", "operator", "--file", str(path)).stdout.strip()
    assert account_of_token(watched.current(), made) is not None


def test_a_file_gone_bad_keeps_the_last_good_accounts_and_is_logged_once(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gridfleet.accounts")
    path = tmp_path / "accounts.toml"
    accounts, texts = with_tokens(people(), "ann")
    write_accounts(accounts, path)
    watched = AccountsFile(path)
    good = watched.current()
    text = dump_accounts(accounts)
    private(path, text.replace('role = "viewer"', 'role = "viewer"\ncolour = "red"'))
    for _ in range(3):
        assert watched.current() is good
    assert watched.problem is not None and "unknown key 'colour'" in watched.problem
    said = [r for r in caplog.records if "colour" in r.getMessage()]
    assert len(said) == 1 and said[0].levelno == logging.ERROR
    path.chmod(0o644)  # another problem: said too, once
    assert watched.current() is good and watched.current() is good
    assert len([r for r in caplog.records if "chmod 600" in r.getMessage()]) == 1
    path.unlink()
    assert watched.current() is good and "gone" in (watched.problem or "")
    _, fewer = revoke_tokens(accounts, "ann", "all")
    write_accounts(fewer, path)
    assert watched.current() == fewer and watched.problem is None
    assert account_of_token(watched.current(), texts["ann"]) is None
    assert any("good again" in r.getMessage() for r in caplog.records)


def test_a_reader_of_a_bad_file_does_not_start(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such accounts file"):
        AccountsFile(tmp_path / "none.toml")
    with pytest.raises(ConfigError, match=re.escape("no [accounts.NAME]")):
        AccountsFile(private(tmp_path / "empty.toml", ""))


# ---- checking a request's header, throttled -----------------------------------------------------


def test_a_header_is_ok_missing_malformed_or_wrong_and_only_wrong_ones_count() -> None:
    accounts, texts = with_tokens(people(), "operator", "ann")
    throttle = token_throttle(Clock())
    check = TokenCheck(lambda: accounts, throttle).check
    ok = check(f"Bearer {texts['ann']}", "10.0.0.1")
    assert isinstance(ok, TokenOk) and ok.account.name == "ann" and ok.account.role == "viewer"
    assert ok.token_id == texts["ann"][5:13]
    assert check(None, "10.0.0.1") == TokenMissing()
    assert isinstance(check("Basic b3A6cHc=", "10.0.0.1"), TokenMalformed)
    assert isinstance(check("Bearer", "10.0.0.1"), TokenMalformed)
    assert len(throttle.addresses) == 0  # nothing counted yet
    garbage = check("Bearer not-a-token", "10.0.0.1")
    assert garbage == TokenWrong("wrong or revoked API token", None, None)
    near = texts["ann"][:-1] + ("x" if texts["ann"][-1] != "x" else "y")
    assert check(f"Bearer {near}", "10.0.0.1") == TokenWrong(
        "wrong or revoked API token", texts["ann"][5:13], "ann"
    )
    assert len(throttle.addresses) == 1 and len(throttle.pairs) == 1
    unknown = "gft1_" + "f" * 8 + texts["ann"][13:]
    assert accounts.token_holder("f" * 8) is None
    assert check(f"Bearer {unknown}", "10.0.0.1") == TokenWrong(
        "wrong or revoked API token", "f" * 8, None
    )
    assert len(throttle.pairs) == 1  # an id nobody holds takes no memory


def test_wrong_tokens_from_one_address_make_it_wait_and_no_other() -> None:
    clock = Clock()
    accounts, texts = with_tokens(people(), "operator")
    check = TokenCheck(lambda: accounts, token_throttle(clock)).check
    right = f"Bearer {texts['operator']}"
    for _ in range(10):  # an address: 10, then one every 6 s
        assert isinstance(check("Bearer gft1_guess", "10.0.0.9"), TokenWrong)
    throttled = check("Bearer gft1_guess", "10.0.0.9")
    assert isinstance(throttled, TokenThrottled) and 0 < throttled.wait_s <= 6
    assert throttled.retry_after == max(1, round(throttled.wait_s))
    assert isinstance(check(right, "10.0.0.9"), TokenThrottled)  # even a right one, there
    assert isinstance(check(right, "10.0.0.2"), TokenOk)  # never from elsewhere
    assert check(None, "10.0.0.9") == TokenMissing()  # the caller may still use a session
    clock.now += throttled.wait_s
    assert isinstance(check(right, "10.0.0.9"), TokenOk)


def test_wrong_secrets_of_one_token_id_make_that_id_wait_at_that_address() -> None:
    clock = Clock()
    accounts, texts = with_tokens(people(), "operator", "ann")
    check = TokenCheck(lambda: accounts, token_throttle(clock)).check
    operator = texts["operator"]
    wrong = f"Bearer {operator[:-1]}{'x' if operator[-1] != 'x' else 'y'}"
    for _ in range(5):  # an id at an address: 5, then one every 12 s
        assert isinstance(check(wrong, "10.0.0.9"), TokenWrong)
    held = check(f"Bearer {operator}", "10.0.0.9")
    assert isinstance(held, TokenThrottled) and held.token_id == operator[5:13]
    assert held.account_name == "operator" and 6 < held.wait_s <= 12
    assert isinstance(check(f"Bearer {texts['ann']}", "10.0.0.9"), TokenOk)  # another id
    assert isinstance(check(f"Bearer {operator}", "10.0.0.3"), TokenOk)  # another address
    clock.now += held.wait_s
    assert isinstance(check(f"Bearer {operator}", "10.0.0.9"), TokenOk)


def test_a_check_on_a_followed_file_refuses_a_revoked_token_at_once(tmp_path: Path) -> None:
    path = tmp_path / "accounts.toml"
    accounts, texts = with_tokens(people(), "dashboard")
    write_accounts(accounts, path)
    check = TokenCheck(AccountsFile(path).current, token_throttle(Clock())).check
    header = f"Bearer {texts['dashboard']}"
    assert isinstance(check(header, "127.0.0.1"), TokenOk)
    _, fewer = revoke_tokens(accounts, "dashboard", "all")
    write_accounts(fewer, path)
    assert isinstance(check(header, "127.0.0.1"), TokenWrong)


# ---- never raises -------------------------------------------------------------------------------

FUZZ_ACCOUNTS, FUZZ_TEXTS = with_tokens(people(), "operator", "ann")


@st.composite
def near_tokens(draw: st.DrawFn) -> str:
    """A real token with a few characters changed, cut or added."""
    text = draw(st.sampled_from(sorted(FUZZ_TEXTS.values())))
    chars = list(text)
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.integers(0, len(chars)))
        what = draw(st.sampled_from(["change", "cut", "add"]))
        piece = draw(st.characters())
        if what == "add" or at == len(chars):
            chars.insert(at, piece)
        elif what == "cut":
            del chars[at]
        else:
            chars[at] = piece
    return "".join(chars)


@settings(max_examples=400, deadline=None)
@given(
    st.one_of(st.text(), st.text(alphabet="gft1_0123456789abcdefAB-", max_size=80), near_tokens())
)
def test_any_text_as_a_token_never_raises_and_opens_only_its_own_account(text: str) -> None:
    found = account_of_token(FUZZ_ACCOUNTS, text)
    if text in FUZZ_TEXTS.values():
        assert found is not None
    else:
        assert found is None
    parsed = parse_token(text)
    assert parsed is None or (TOKEN_FORM.fullmatch(text) and parsed.text == text)


@settings(max_examples=400, deadline=None)
@given(
    st.one_of(
        st.none(),
        st.text(),
        st.builds(
            lambda s, t: s + t, st.sampled_from(["Bearer ", "bearer", "Bearer  "]), st.text()
        ),
        st.builds("Bearer {}".format, near_tokens()),
    )
)
def test_any_authorization_header_never_raises(header: str | None) -> None:
    got = bearer_token(header)
    assert got is None or isinstance(got, (str, MalformedHeader))
    assert (got is None) == (header is None)
    if isinstance(got, str):
        assert got and " " not in got and header is not None and got in header
    verdict = TokenCheck(lambda: FUZZ_ACCOUNTS, token_throttle(Clock())).check(header, "::1")
    assert isinstance(verdict, (TokenOk, TokenMissing, TokenMalformed, TokenWrong))
    assert isinstance(verdict, TokenOk) == (got in FUZZ_TEXTS.values())
