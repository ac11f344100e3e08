"""A page session's own broker password, pure: made, checked and taken back (session_login.py),
and what the embedded broker's gate and the dashboard's session book do with them."""

from __future__ import annotations

import json
from collections.abc import Callable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jsonschema import Draft202012Validator

from gridfleet.accounts import Accounts, default_accounts, rules
from gridfleet.broker.gate import Gate
from gridfleet.dashboard.login import SessionBook
from gridfleet.dashboard.settings import DashboardSettings
from gridfleet.errors import ConfigError
from gridfleet.protocol import PROTOCOL_VERSION, HeaderStamper, Topics, encode
from gridfleet.protocol.messages import BrokerRevoke
from gridfleet.session_login import (
    MAX_REVOKED,
    RevokedSessions,
    make_session_password,
    read_session_password,
    session_password_refusal,
)
from gridfleet.throttle import LoginThrottle

from support.paths import REPO

ACCOUNTS = default_accounts(["unit1"])
OPERATOR = ACCOUNTS.get("operator")
NOW = 1_800_000_000.0
ENDS = int(NOW) + 3600
BROKER = "mqtt://127.0.0.1:1"


def password(sid: str = "s1", expires: int = ENDS, name: str = "operator") -> str:
    """A session password of `name` (the operator's account password as its key)."""
    return make_session_password(name, OPERATOR.password, sid, expires)


def test_a_session_password_says_its_session_and_end_and_checks_for_its_account() -> None:
    made = password()
    claim = read_session_password(made)
    assert claim is not None and (claim.sid, claim.expires) == ("s1", ENDS)
    assert made.startswith(f"gf1.s1.{ENDS}.") and OPERATOR.password not in made
    assert session_password_refusal("operator", OPERATOR.password, made, NOW) is None


def test_an_expired_session_password_is_refused() -> None:
    made = password()
    assert session_password_refusal("operator", OPERATOR.password, made, ENDS) == (
        "a session password that has expired"
    )


def test_a_session_password_opens_no_other_account() -> None:
    made = password()
    dashboard = ACCOUNTS.get("dashboard")
    assert session_password_refusal("dashboard", dashboard.password, made, NOW) == (
        "a session password not made for this account"
    )
    # Nor is one made with another account's key this account's, even naming it.
    other = make_session_password("operator", dashboard.password, "s1", ENDS)
    assert session_password_refusal("operator", OPERATOR.password, other, NOW) is not None


@pytest.mark.parametrize(
    "tampered",
    [
        lambda p: p[:-1] + ("A" if p[-1] != "A" else "B"),  # another MAC
        lambda p: p.replace(f".{ENDS}.", f".{ENDS + 3600}."),  # a later end
        lambda p: p.replace("gf1.s1.", "gf1.s2."),  # another session
        lambda p: p + "x",  # not the shape
        lambda p: p.replace("gf1", "gf2"),
    ],
)
def test_a_tampered_session_password_is_refused(tampered: Callable[[str], str]) -> None:
    made = tampered(password())
    assert session_password_refusal("operator", OPERATOR.password, made, NOW) is not None


def test_a_revoked_session_password_is_refused_and_others_are_not() -> None:
    revoked = RevokedSessions()
    assert revoked.revoke("s1", ENDS, NOW)
    assert session_password_refusal("operator", OPERATOR.password, password(), NOW, revoked) == (
        "a session password taken back at logout"
    )
    other = password("s2")
    assert session_password_refusal("operator", OPERATOR.password, other, NOW, revoked) is None


def test_a_revocation_is_forgotten_once_its_session_has_ended() -> None:
    revoked = RevokedSessions()
    assert revoked.revoke("s1", ENDS, NOW) and revoked.revoke("s2", ENDS + 10, NOW)
    assert not revoked.revoke("s3", ENDS, ENDS)  # ended already: nothing to keep
    assert revoked.live(ENDS) == {"s2": ENDS + 10}
    assert not revoked.is_revoked("s1", ENDS)
    assert len(revoked) == 1


def test_the_revocations_kept_are_bounded_soonest_end_first() -> None:
    revoked = RevokedSessions(limit=3)
    for n in range(5):
        revoked.revoke(f"s{n}", ENDS + n, NOW)
    assert set(revoked.live(NOW)) == {"s2", "s3", "s4"}
    assert MAX_REVOKED >= 10_000


def test_a_session_id_that_is_no_base64url_makes_no_password() -> None:
    with pytest.raises(ValueError, match="base64url"):
        make_session_password("operator", OPERATOR.password, "a.b", ENDS)


# ---- the embedded broker's gate -----------------------------------------------------------


class Wall:
    def __init__(self) -> None:
        self.now = NOW

    def __call__(self) -> float:
        return self.now


def gate(wall: Wall) -> Gate:
    throttle = LoginThrottle(
        pair_burst=2, pair_per_s=0.001, address_burst=10, address_per_s=0.001, clock=wall
    )
    return Gate(ACCOUNTS, clock=wall, throttle=throttle, root="site", wall=wall)


def revoke_payload(sid: str, expires: int = ENDS, sender: str = "dashboard-x") -> bytes:
    return encode(BrokerRevoke(header=HeaderStamper(sender)("revoke"), sid=sid, expires=expires))


def test_the_gate_lets_a_session_password_in_for_its_account_until_its_end() -> None:
    wall = Wall()
    g = gate(wall)
    assert g.refusal("operator", password(), "operator-page-1", "10.0.0.1") is None
    assert g.refusal("operator", OPERATOR.password, "operator-cli", "10.0.0.1") is None
    why = g.refusal("dashboard", password(), "dashboard-page-1", "10.0.0.1")
    assert why is not None and "not made for this account" in why
    wall.now = ENDS
    why = g.refusal("operator", password(), "operator-page-1", "10.0.0.1")
    assert why is not None and "expired" in why


def test_the_gate_counts_a_bad_session_password_as_a_failed_login() -> None:
    wall = Wall()
    g = gate(wall)
    for _ in range(2):
        assert g.refusal("operator", password()[:-2] + "xx", "operator-page", "10.0.0.1")
    why = g.refusal("operator", password(), "operator-page", "10.0.0.1")
    assert why is not None and "too many failed logins" in why  # that pair's budget is spent
    assert g.refusal("operator", password(), "operator-page", "10.0.0.2") is None


def test_a_dashboard_account_revokes_a_session_and_nobody_else_does() -> None:
    wall = Wall()
    g = gate(wall)
    assert g.revoke_topic == Topics("site").fleet("revoke")
    refused = g.revocation("operator", revoke_payload("s1", sender="operator-x"))
    assert refused.sid is None and "not a dashboard account" in refused.words
    assert g.refusal("operator", password(), "operator-page", "10.0.0.1") is None
    assert g.revocation("dashboard", b"{not json").sid is None
    taken = g.revocation("dashboard", revoke_payload("s1"))
    assert taken.sid == "s1"
    why = g.refusal("operator", password(), "operator-page", "10.0.0.1")
    assert why is not None and "taken back at logout" in why
    assert g.refusal("operator", password("s2"), "operator-page", "10.0.0.1") is None


def test_a_revocation_cannot_be_a_last_will() -> None:
    g = gate(Wall())
    why = g.refused_will("dashboard", g.revoke_topic, revoke_payload("s1"))
    assert why is not None and "never a last will" in why


def test_only_the_dashboard_role_may_publish_revocations_and_viewers_do_not_read_them() -> None:
    topics = Topics("site")
    topic = topics.fleet("revoke")
    for account in ACCOUNTS.accounts.values():
        allowed = rules(account, topics)
        assert (topic in allowed.publish) == (account.role == "dashboard"), account.name
        if account.role == "viewer":
            assert not any(s.startswith(f"{topics.prefix}/broker") for s in allowed.subscribe)


# ---- the dashboard's side -----------------------------------------------------------------


def test_the_session_book_tells_of_sessions_closed_before_their_end() -> None:
    ended: list[tuple[str, int]] = []
    book = SessionBook(
        lifetime_s=60, per_account=2, wall=lambda: NOW, closed=lambda s, e: ended.append((s, e))
    )
    first, second = book.open("ann"), book.open("ann")
    assert book.expires(first) == int(NOW) + 60
    book.close(second)  # a logout
    third = book.open("ann")
    book.open("ann")  # the oldest of ann's two is closed: an eviction
    assert ended == [(second, int(NOW) + 60), (first, int(NOW) + 60)]
    assert book.expires(first) is None and book.user_of(third) == "ann"
    book.close("unknown")
    assert len(ended) == 2


def test_session_passwords_need_accounts_a_dashboard_account_and_its_broker() -> None:
    with pytest.raises(ConfigError, match="with accounts"):
        DashboardSettings(session_passwords=True)
    with pytest.raises(ConfigError, match="--audit-broker"):
        DashboardSettings(accounts=ACCOUNTS, session_passwords=True)
    people = Accounts({n: a for n, a in ACCOUNTS.accounts.items() if a.role != "dashboard"})
    with pytest.raises(ConfigError, match="dashboard account"):
        DashboardSettings(accounts=people, audit_broker=BROKER, session_passwords=True)
    DashboardSettings(accounts=ACCOUNTS, audit_broker=BROKER, session_passwords=True)


BROKER_REVOKE_SCHEMA = json.loads((REPO / "protocol/schemas/BrokerRevoke.json").read_text("utf-8"))
HEADERS = st.fixed_dictionaries(
    {
        "seq": st.integers(0, 9),
        "timestamp": st.just("2026-11-21T10:00:00Z"),
        "sender": st.from_regex(r"\Adashboard-[a-z0-9]{1,8}\Z"),
    },
    optional={"version": st.just(PROTOCOL_VERSION)},
)
ALLOWED = st.fixed_dictionaries(
    {
        "header": HEADERS,
        "sid": st.from_regex(r"\A[A-Za-z0-9_-]{1,64}\Z"),
        "expires": st.integers(0, 2 * ENDS),  # ended, or not yet
    }
)
# What the schema allows, and each of those with one field dropped or replaced by a wrong value
# (a sid of other characters or too long, an end as a float, a string or negative, an extra key).
WRONG = st.none() | st.integers(-5, -1) | st.floats(0, ENDS) | st.text(max_size=70)


@st.composite
def revocations(draw: st.DrawFn) -> dict[str, object]:
    message = draw(ALLOWED)
    change = draw(st.sampled_from(["none", "drop", "replace", "extra"]))
    key = draw(st.sampled_from(sorted(message)))
    if change == "drop":
        del message[key]
    elif change == "replace":
        message[key] = draw(WRONG)
    elif change == "extra":
        message["extra"] = draw(WRONG)
    return message


REVOCATIONS = revocations()


@settings(max_examples=300, deadline=None)
@given(message=REVOCATIONS)
def test_a_revocation_is_taken_exactly_when_its_schema_allows_it(
    message: dict[str, object],
) -> None:
    allowed = Draft202012Validator(BROKER_REVOKE_SCHEMA).is_valid(message)
    taken = gate(Wall()).revocation("dashboard", json.dumps(message).encode())
    if not allowed:  # refused in words, nothing revoked
        assert taken.sid is None and "not a revocation" in taken.words, (message, taken)
        return
    assert "not a revocation" not in taken.words, (message, taken)
    ended = int(message["expires"]) <= NOW  # type: ignore[call-overload]
    assert taken.sid == (None if ended else message["sid"])
