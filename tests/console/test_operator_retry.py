"""An operator re-sends a request, the same, until its reply comes; then gives up in words."""

from __future__ import annotations

import asyncio
import json
import re
from collections.abc import Callable

import pytest

from gridfleet.console.operator import operator_session
from gridfleet.errors import GridfleetError
from gridfleet.grid import Cell
from gridfleet.protocol import Reply, Topics, encode
from gridfleet.system.broker_thread import BrokerThread

from support.effects import header
from support.probe import MqttProbe
from support.wait import async_wait_for


async def test_a_request_is_sent_again_with_its_id_until_the_reply_comes(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    topics = Topics(root)
    coordinator = probe_factory()  # stands in for a coordinator whose replies were lost
    coordinator.subscribe(topics.request("submit_job"))
    async with operator_session(broker.url, topics, "op", retry_s=0.05) as op:
        sending = asyncio.create_task(op.submit_job(Cell(1, 1), Cell(2, 2), 1.0, timeout=30))
        copies = await async_wait_for(
            lambda: (
                (seen := coordinator.received(topics.request("submit_job")))
                and len(seen) >= 3
                and seen
            ),
            what="three copies of the request",
        )
        sent = [json.loads(c.payload) for c in copies]
        assert all(s == sent[0] for s in sent), "the same request each time, id and all"
        assert not sending.done()
        rid = sent[0]["request_id"]
        answer = Reply(header=header("coordinator"), request_id=rid, accepted=True, job_id="j")
        coordinator.publish(topics.reply("op"), encode(answer))
        reply = await asyncio.wait_for(sending, 10)
        assert (reply.accepted, reply.job_id) == (True, "j")
        assert op.resent == len(coordinator.received(topics.request("submit_job"))) - 1


async def test_without_a_coordinator_the_operator_gives_up_in_one_sentence(
    broker: BrokerThread, root: str, probe_factory: Callable[..., MqttProbe]
) -> None:
    topics = Topics(root)
    listener = probe_factory()
    listener.subscribe(topics.request("cancel_job"))
    async with operator_session(broker.url, topics, "op", retry_s=0.1) as op:
        with pytest.raises(GridfleetError) as failed:
            await op.cancel_job("j1", timeout=1.0)
    found = re.fullmatch(
        r"no reply from the coordinator to cancel_job (\S+) after (\d+) tries over 1 s: "
        r"is it running\?",
        str(failed.value),
    )
    assert found is not None, str(failed.value)
    # Backing off: 0.1, 0.2, 0.4 s between tries, so at most 4 in 1 s, at least 2.
    assert 2 <= int(found[2]) <= 4
    await async_wait_for(
        lambda: len(listener.received(topics.request("cancel_job"))) == int(found[2]),
        what="every try on the broker",
    )
    ids = {
        json.loads(m.payload)["request_id"] for m in listener.received(topics.request("cancel_job"))
    }
    assert ids == {found[1]}
