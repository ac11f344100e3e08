"""The embedded broker's gate and the login throttle, pure: a clock that the test moves."""

from __future__ import annotations

import json

import pytest

from gridfleet.accounts import VehicleLink, default_accounts
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


def test_the_throttle_counts_names_and_addresses_apart() -> None:
    clock = Clock()
    throttle = LoginThrottle(
        name_burst=2, name_per_s=1, address_burst=3, address_per_s=1, clock=clock
    )
    throttle.failed("operator", "10.0.0.1", known_name=True)
    throttle.failed("operator", "10.0.0.2", known_name=True)
    assert throttle.wait_s("operator", "10.0.0.3") > 0  # a third address gains nothing
    assert throttle.wait_s("dashboard", "10.0.0.1") == 0
    for n in range(3):  # made-up names count only against their address
        throttle.failed(f"nobody{n}", "10.0.0.9", known_name=False)
    assert throttle.wait_s("dashboard", "10.0.0.9") > 0
    assert throttle.wait_s("nobody0", "10.0.0.8") == 0


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


def test_the_gate_throttles_a_name_under_a_flood_and_recovers() -> None:
    clock = Clock()
    gate = Gate(ACCOUNTS, clock=clock)
    for n in range(10):
        gate.refusal("operator", "guess", "operator", f"10.0.0.{n}")
    # The right password waits too while the name is spent: the flood costs nothing to check.
    refusal = gate.refusal("operator", PASSWORD["operator"], "operator", "10.0.1.1")
    assert refusal is not None and "too many failed logins" in refusal
    assert gate.refusal("coordinator", PASSWORD["coordinator"], "coordinator", "10.0.0.1") is None
    clock.now += 1.0
    assert gate.refusal("operator", PASSWORD["operator"], "operator", "10.0.1.1") is None


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
