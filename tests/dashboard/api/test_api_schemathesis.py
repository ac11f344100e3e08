"""schemathesis against the served OpenAPI document, with an operator's token, over a real fleet
(its broker checking accounts): for every operation, generated requests that fit the document
and requests that break it. No answer is a 500 (nor any 5xx: the fleet is up), every answer is
one the document lists, in its content type and shape, and a request the document forbids is
refused. The event stream (/events, unbounded by design) has its own tests."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    ignored_auth,
    negative_data_rejection,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from gridfleet.accounts import default_accounts, write_accounts
from gridfleet.dashboard.api.context import EXTENSION
from gridfleet.protocol import Topics
from gridfleet.protocol.constants import DEFAULT_ROOT
from gridfleet.scenario import load_scenario
from gridfleet.system.assembly import Assembly, SystemSpec
from gridfleet.throttle import LoginThrottle

from support.api_client import ApiServer, online, serving, with_token
from support.mosquitto import mosquitto_with_accounts
from support.paths import MAPS

pytestmark = pytest.mark.slow  # ~30 s: a few hundred requests against a running fleet
PLAYFIELD = MAPS / "playfield.toml"
EXAMPLES = 25  # per operation and mode: bounded, so the whole run stays well under a minute
CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    response_headers_conformance,
    negative_data_rejection,
    ignored_auth,
]


# On the embedded broker (it checks the accounts and the page sessions' passwords) and, asked
# for it (`make test` asks for both), on Mosquitto with the accounts `gridfleet accounts
# mosquitto` writes.
LANES = [k for k in os.environ.get("GRIDFLEET_TEST_BROKER", "amqtt").split(",") if k]


@pytest.fixture(params=LANES)
def served(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[ApiServer, str]]:
    """The API of a fleet whose broker checks accounts, and an operator's token."""
    scenario = load_scenario(PLAYFIELD)
    accounts = default_accounts([u.id for u in scenario.units])
    path = tmp_path / "accounts.toml"
    token, _, accounts = with_token(path, accounts, "operator")
    write_accounts(accounts, path)
    with contextlib.ExitStack() as stack:
        embedded = request.param == "amqtt"
        url = None
        if not embedded:
            url = stack.enter_context(
                mosquitto_with_accounts(accounts, Topics(DEFAULT_ROOT), tmp_path / "mosquitto")
            )
        spec = SystemSpec(
            scenario,
            broker=url,
            root=DEFAULT_ROOT,
            step_s=0.05,
            db_path=tmp_path / "jobs.db",
            accounts=accounts,
            ws_port=None,
        )
        assembly = Assembly(spec, "threads")
        stack.callback(assembly.stop)
        system = assembly.start_threads()
        api = stack.enter_context(
            serving(
                system.url,
                DEFAULT_ROOT,
                accounts=accounts,
                accounts_file=path,
                session_passwords=embedded,
            )
        )
        # schemathesis sends wrong tokens on purpose (ignored_auth): it must not be throttled
        # for them, or every later answer would be a 429 (the throttle has its own test).
        context = api.server.app.extensions[EXTENSION]
        assert context.identity.check is not None
        context.identity.check.throttle = LoginThrottle(
            pair_burst=10**6, pair_per_s=1.0, address_burst=10**6, address_per_s=1.0
        )
        yield api, token


@pytest.mark.timeout(180)  # 45 s alone on a quiet machine; over 60 s beside make test's others
def test_every_answer_fits_the_document_and_none_is_a_server_error(
    served: tuple[ApiServer, str],
) -> None:
    api, token = served
    with api.client(token) as client:
        online(client)
    # The operator's token as the document's own bearer scheme: schemathesis then knows which
    # requests carry it, and sends some without it (and with a wrong one) on purpose.
    config = schemathesis.Config.from_dict({"auth": {"openapi": {"bearer": {"bearer": token}}}})
    schema = schemathesis.openapi.from_url(f"{api.base}/openapi.json", config=config).exclude(
        path="/api/v1/events"
    )
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 17, [o.label for o in operations]
    for operation in operations:
        # The document's own examples first (a job by place names: accepted), then generated
        # requests that fit the document, then requests that break it.
        runs = [
            (operation.as_strategy(generation_mode=GenerationMode.POSITIVE), EXAMPLES),
            (operation.as_strategy(generation_mode=GenerationMode.NEGATIVE), EXAMPLES),
        ]
        examples = schema.get_strategies_from_examples(operation)
        if examples:
            runs.insert(0, (st.one_of(examples), 3 * len(examples)))
        for cases, count in runs:

            @settings(
                max_examples=count,
                deadline=None,
                database=None,
                derandomize=True,  # the same cases every run: a failure comes back
                phases=[Phase.explicit, Phase.generate],
                suppress_health_check=list(HealthCheck),
            )
            @given(case=cases)
            def call(case: schemathesis.Case) -> None:
                case.call_and_validate(base_url=api.server.url, checks=CHECKS)

            call()
