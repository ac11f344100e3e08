"""A late last will after a failover does not leave a live unit lost (protocol.md §4.1, §8).

On a clustered broker (aedes, EMQX, VerneMQ) a node that dies leaves its clients' last wills to a
survivor, which publishes them seconds to minutes later (tests/broker/test_aedes_cluster.py): by
then the unit is online on another node, and its old session's `broken` overwrites its retained
`connection`. Here on two independent embedded brokers: everyone fails over from A to B, then a
probe on B publishes, retained, the `broken` of the unit's first session (stamped before it),
standing in for the survivor's late will. The unit says `online` again; the coordinator counts it
active again within its loss timeout, and a reader that comes later reads `online`.
"""

from __future__ import annotations

import asyncio
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

from test_failover_stop import T, all_on, brokers, fleet_on

from gridfleet.protocol import Connection, Header, decode, encode

from support.probe import MqttProbe
from support.wait import wait_for


def test_a_late_will_on_the_next_broker_is_set_right_by_the_unit_and_it_stays_in_the_fleet(
    tmp_path: Path,
) -> None:
    with brokers(2) as (a, b), fleet_on(tmp_path, f"{a.url},{b.url}") as (coordinator, fleet):
        core = coordinator.service.core
        world = core.world
        unit = sorted(fleet.service.shells)[0]
        shell = fleet.service.shells[unit]

        def record() -> tuple[str | None, bool]:
            """The coordinator's `connection` of the unit, and whether it counts it active."""

            def read() -> tuple[str | None, bool]:
                rec = world.units.get(unit)  # None: not heard yet
                if rec is None:
                    return None, False
                return rec.connection, world.is_active(rec, asyncio.get_running_loop().time())

            return coordinator.call(read)

        wait_for(lambda: record() == ("online", True), 20, what="the unit active on broker A")
        a.stop()
        wait_for(lambda: all_on(coordinator, fleet, b.url), 30, what="all on broker B")
        wait_for(lambda: record() == ("online", True), 20, what="the unit active on broker B")
        loss_s = coordinator.call(lambda: world.stale_after_s(world.units[unit]))
        # The will of the unit's first session (seq 0), stamped well before its `online`s.
        stamped = datetime.now(UTC) - timedelta(seconds=60)
        will = Connection(header=Header(seq=0, timestamp=stamped, sender=unit), state="broken")
        topic = T.unit("connection", unit)
        with MqttProbe(b.url) as survivor:
            survivor.subscribe(topic)
            survivor.wait(topic, lambda m: decode(Connection, m.payload).state == "online")
            sent_at = time.monotonic()
            survivor.publish(topic, encode(will), qos=1, retain=True)
            survivor.wait(topic, lambda m: m.payload == encode(will))  # it went out on B
            again = survivor.wait(
                topic, lambda m: m.at > sent_at and decode(Connection, m.payload).state == "online"
            )
        answered = decode(Connection, again.payload)
        assert answered.header.sender == unit and answered.header.timestamp > stamped
        assert fleet.call(lambda: shell.core.connection_corrections) >= 1
        # Back within its loss timeout (1 s at the 0.2 s step), counted from the correction.
        wait_for(lambda: record() == ("online", True), loss_s, what="the unit counted active")
        # A coordinator or page that starts later reads the unit `online` (retained on B).
        with MqttProbe(b.url) as later:
            later.subscribe(topic)
            kept = later.wait(topic)
            assert kept.retain and decode(Connection, kept.payload).state == "online"
