"""The embedded broker's gate and the login throttle, pure: a clock that the test moves."""

from __future__ import annotations

import json

import pytest

from gridfleet.accounts import Account, VehicleLink, default_accounts
from gridfleet.broker.gate import Gate, owner_of
from gridfleet.throttle import FailureBudget, LoginThrottle

ACCOUNTS = default_accounts(["unit1", "unit10"], [VehicleLink("agv1", "uagv/v2/acme/sn-1")])
PASSWORD = {name: a.password for name, a in ACCOUNTS.accounts.items()}


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def test_a_budget_refuses_once_spent_and_refills_with_time() -> None:
    clock = Clock()
    budget = FailureBudget(burst=3, per_s=0.5, clock=clock)
    for _ in range(3):
        assert budget.wait_s("a") == 0
        budget.failed("a")
    assert budget.wait_s("a") == pytest.approx(2.0) and budget.wait_s("b") == 0
    clock.now += 2.0
    assert budget.wait_s("a") == 0  # one failure's worth came back
    budget.failed("a")
    assert budget.wait_s("a") == pytest.approx(2.0)


def test_a_budget_remembers_a_bounded_number_of_keys() -> None:
    budget = FailureBudget(burst=1, per_s=1.0, max_keys=2)
    for key in "abc":
        budget.failed(key)
    assert budget.wait_s("a") == 0 and budget.wait_s("c") > 0  # the oldest was forgotten


def test_the_throttle_counts_addresses_and_name_address_pairs_apart() -> None:
    clock = Clock()
    throttle = LoginThrottle(
        pair_burst=2, pair_per_s=1, address_burst=3, address_per_s=1, clock=clock
    )
    throttle.failed("operator", "10.0.0.1", known_name=True)
    throttle.failed("operator", "10.0.0.1", known_name=True)
    assert throttle.wait_s("operator", "10.0.0.1") > 0  # that name from that address waits
    assert throttle.wait_s("dashboard", "10.0.0.1") == 0  # the address has one failure left
    assert throttle.wait_s("operator", "10.0.0.3") == 0  # another address is not touched
    for n in range(3):  # made-up names count only against their address
        throttle.failed(f"nobody{n}", "10.0.0.9", known_name=False)
    assert throttle.wait_s("dashboard", "10.0.0.9") > 0
    assert throttle.wait_s("nobody0", "10.0.0.8") == 0
    assert len(throttle.pairs) == 1  # made-up names take no memory of their own


@pytest.mark.parametrize("per_s", [3, 100])
def test_wrong_passwords_from_one_address_never_make_a_right_login_from_another_wait(
    per_s: int,
) -> None:
    # As found: wrong passwords for `operator` from another address, 3 a second, refused 17 of
    # 18 of the operator's own logins (the budget was kept per name). The broker's address budget.
    clock = Clock()
    throttle = LoginThrottle(address_burst=20, address_per_s=1.0, clock=clock)
    for n in range(60 * per_s):  # for a minute, as the caller does: checked unless waiting
        if throttle.wait_s("operator", "10.0.0.2") == 0:
            throttle.failed("operator", "10.0.0.2", known_name=True)
        assert throttle.wait_s("operator", "10.0.0.1") == 0, f"the operator waits after {n}"
        clock.now += 1 / per_s
    assert throttle.wait_s("operator", "10.0.0.2") > 0  # the guessing address waits


def test_one_clients_wrong_password_leaves_the_others_at_its_address_in() -> None:
    # `gridfleet up` runs every component from one address: a unit retrying a stale password
    # must not shut the coordinator out.
    clock = Clock()
    throttle = LoginThrottle(clock=clock)
    for _ in range(600):  # ten a second for a minute
        if throttle.wait_s("unit1", "127.0.0.1") == 0:
            throttle.failed("unit1", "127.0.0.1", known_name=True)
        assert throttle.wait_s("coordinator", "127.0.0.1") == 0
        clock.now += 0.1
    assert throttle.wait_s("unit1", "127.0.0.1") > 0


def test_the_throttle_remembers_a_bounded_number_of_addresses_and_pairs() -> None:
    throttle = LoginThrottle(max_keys=100)
    for n in range(5000):
        throttle.failed("operator", f"10.{n // 65536}.{n // 256 % 256}.{n % 256}", known_name=True)
    assert len(throttle.addresses) == 100 and len(throttle.pairs) == 100


def test_the_gate_lets_in_the_right_password_with_an_owned_client_id() -> None:
    gate = Gate(ACCOUNTS)
    for client_id in ("unit1", "unit1-3fa2c1d0", "unit1@hall.b", ""):
        assert gate.refusal("unit1", PASSWORD["unit1"], client_id, "10.0.0.1") is None


def test_a_vehicle_uses_the_client_id_its_vendor_chose_if_no_account_owns_it() -> None:
    # vda-5050-lib and vendors' vehicles pick their own client ids; gridfleet's own clients
    # take one their account owns (bus.py).
    gate = Gate(ACCOUNTS)
    for client_id in ("agv1", "acme_sn-1", "AGV-sn-1-4f2a"):
        assert gate.refusal("agv1", PASSWORD["agv1"], client_id, "10.0.0.1") is None
    for owned in ("coordinator", "unit1-x", "vda5050"):  # never one an account owns
        refusal = gate.refusal("agv1", PASSWORD["agv1"], owned, "10.0.0.1")
        assert refusal is not None and "belongs to account" in refusal


@pytest.mark.parametrize(
    ("user", "password", "client_id", "words"),
    [
        (None, None, "x", "no user name"),
        ("unit1", "wrong password", "unit1", "wrong user name or password"),
        ("nobody", "whatever", "nobody", "wrong user name or password"),
        ("unit1", None, "unit1", "wrong user name or password"),
        ("device-unit1", "", "device-unit1", "wrong user name or password"),
        ("device-unit1", "device-unit1", "coordinator", "belongs to account 'coordinator'"),
        ("unit1", "unit1", "unit10-x", "belongs to account 'unit10'"),
        ("unit1", "unit1", "probe-1", "belongs to no account"),
    ],
)
def test_the_gate_refuses_with_the_reason(
    user: str | None, password: str | None, client_id: str, words: str
) -> None:
    # A password equal to the user's name stands for that account's real password.
    given = PASSWORD.get(password, password) if password else password
    refusal = Gate(ACCOUNTS).refusal(user, given, client_id, "10.0.0.1")
    assert refusal is not None and words in refusal


def test_the_gate_throttles_a_flooding_address_and_it_recovers() -> None:
    clock = Clock()
    gate = Gate(ACCOUNTS, clock=clock)
    for n in range(30):
        gate.refusal(f"guess{n}", "guess", "operator", "10.0.0.9")
    # The right password waits too from the spent address: the flood costs nothing to check.
    refusal = gate.refusal("operator", PASSWORD["operator"], "operator", "10.0.0.9")
    assert refusal is not None and "too many failed logins" in refusal and "10.0.0.9" in refusal
    assert gate.refusal("operator", PASSWORD["operator"], "operator", "10.0.1.1") is None
    clock.now += 1.0
    assert gate.refusal("operator", PASSWORD["operator"], "operator", "10.0.0.9") is None


@pytest.mark.parametrize("per_s", [3, 100])
@pytest.mark.parametrize("name", ["operator", "coordinator", "device-unit1"])
def test_the_gate_lets_an_account_in_whatever_another_address_guesses(
    name: str, per_s: int
) -> None:
    clock = Clock()
    gate = Gate(ACCOUNTS, clock=clock)
    for n in range(60 * per_s):  # wrong passwords for `name` from 10.0.0.2, for a minute
        gate.refusal(name, "guess", name, "10.0.0.2")
        if n % per_s == 0:  # and its right password from 10.0.0.1, once a second
            assert gate.refusal(name, PASSWORD[name], name, "10.0.0.1") is None, n
        clock.now += 1 / per_s
    refusal = gate.refusal(name, PASSWORD[name], name, "10.0.0.2")
    assert refusal is not None and "too many failed logins" in refusal  # the guesser waits


def test_the_longest_account_name_owns_a_client_id() -> None:
    names = ["unit1", "unit10", "device", "device-unit1"]
    assert owner_of("unit10-x", names) == "unit10"
    assert owner_of("device-unit1", names) == "device-unit1"
    assert owner_of("device-unit2", names) == "device"
    assert owner_of("unit1x", names) is None


def test_a_request_or_report_must_name_a_sender_its_account_owns() -> None:
    gate, submit = Gate(ACCOUNTS), "gridfleet/v1/requests/clear_obstacles"

    def signed(sender: object) -> bytes:
        return json.dumps({"header": {"sender": sender}, "squares": None}).encode()

    assert gate.refused_publish("operator", "operator-cli", submit, signed("operator-cli")) is None
    refused = gate.refused_publish("operator", "operator-cli", submit, signed("coordinator"))
    assert refused is not None and "'coordinator', an id account 'operator' does not own" in refused
    # What cannot be read passes: the coordinator refuses it in words.
    for unreadable in (b"{not json", b"[]", signed(7)):
        assert gate.refused_publish("operator", "operator-cli", submit, unreadable) is None
    assert gate.refused_publish("unit1", "unit1", "gridfleet/v1/units/unit1/state", b"x") is None


def test_error_reports_are_a_burst_of_20_then_5_a_second_per_client() -> None:
    clock = Clock()
    gate, errors = Gate(ACCOUNTS, clock=clock), "gridfleet/v1/errors"
    report = json.dumps({"header": {"sender": "unit1"}}).encode()
    passed = [gate.refused_publish("unit1", "unit1", errors, report) is None for _ in range(30)]
    assert passed == [True] * 20 + [False] * 10
    assert gate.refused_publish("unit10", "unit10", errors, report.replace(b"1", b"10")) is None
    clock.now += 1.0
    passed = [gate.refused_publish("unit1", "unit1", errors, report) is None for _ in range(10)]
    assert passed == [True] * 5 + [False] * 5


def test_a_will_is_held_to_every_rule_a_publish_is_without_spending_the_error_budget() -> None:
    # As found: a will skipped these checks (amqtt sends it itself, at the end of the session):
    # a will on requests/cancel_job naming `operator`, from another account, was audited as the
    # operator's, verified; a device's will on errors went out as the coordinator's.
    accounts = ACCOUNTS.with_account(Account("ann", "ann's password", "operator"))
    gate = Gate(accounts)

    def signed(sender: str) -> bytes:
        return json.dumps({"header": {"sender": sender}, "request_id": "r1"}).encode()

    cancel, ack = "gridfleet/v1/requests/cancel_job", "gridfleet/v1/requests/ack_alert"
    errors, latch = "gridfleet/v1/errors", "gridfleet/v1/fleet/estop"
    forged = [
        ("ann", cancel, signed("operator")),
        ("ann", ack, signed("operator-cli-1")),
        ("ann", latch, b"engaged|operator|a will"),
        ("device-unit1", errors, signed("coordinator")),
    ]
    for user, topic, data in forged:
        refused = gate.refused_will(user, topic, data)
        assert refused is not None and f"an id account {user!r} does not own" in refused, topic
    for user, topic, data in [
        ("ann", cancel, signed("ann-cli")),
        ("ann", latch, b"engaged|ann@desk|a will"),
        ("coordinator", latch, b"engaged|device-unit1|copied"),  # it copies presses
        ("unit1", "gridfleet/v1/units/unit1/connection", b"offline"),
    ]:
        assert gate.refused_will(user, topic, data) is None, topic
    # Checking a will on errors spends none of the client's error reports.
    for _ in range(30):
        assert gate.refused_will("unit1", errors, signed("unit1")) is None
    passed = [
        gate.refused_publish("unit1", "unit1", errors, signed("unit1")) is None for _ in range(21)
    ]
    assert passed == [True] * 20 + [False]


def test_the_coordinator_may_only_clear_a_removed_units_own_topics_never_write_them() -> None:
    # The coordinator's account publishes on units/+/{state,factsheet,vehicle,connection} to
    # clear a removed unit's retained copies (protocol.md §6.11): an empty payload, nothing else.
    gate = Gate(ACCOUNTS)
    for kind in ("state", "factsheet", "vehicle", "connection"):
        topic = f"gridfleet/v1/units/unit1/{kind}"
        assert gate.refused_publish("coordinator", "coordinator", topic, b"") is None
        refused = gate.refused_publish("coordinator", "coordinator", topic, b'{"status": "idle"}')
        assert refused is not None and "never writes them" in refused
        # The unit itself writes its own, as ever.
        assert gate.refused_publish("unit1", "unit1", topic, b'{"status": "idle"}') is None
    order = "gridfleet/v1/units/unit1/order"
    assert gate.refused_publish("coordinator", "coordinator", order, b'{"x": 1}') is None
