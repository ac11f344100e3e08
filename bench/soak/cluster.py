"""The soak on a broker cluster (`gridfleet bench soak --cluster aedes|rabbitmq`).

The soak starts the cluster (`gridfleet.broker.aedes_cluster`, `gridfleet.broker.rabbitmq_cluster`)
and gives each component the cluster's nodes as its broker list, each component's list beginning
at another node (coordinator on node 0, units on node 1, feed on node 2, ...): a component whose
node dies moves to the next one (`gridfleet.endpoint`). Each component reaches each node through
a proxy of its own (`FaultyProxy`), so the soak knows which node every component is on (the proxy
with open links) and a cut strikes one node's clients only. The listener, the soak's operator and
device reach the nodes directly, the nodes down last in their lists.

Node faults, on the node one component is on (drawn among coordinator, units, feed): `kill_node`
(SIGKILL; once the fleet moves again, the node is started again and rejoins), `pause_node`
(SIGSTOP for 1-5 s, or past the clients' keep-alive, then SIGCONT) and `cut_node` (its proxies
drop every link and refuse new ones for 0.5-5 s).

Recovery of a node fault: from the fault (the SIGKILL, SIGSTOP or cut) to the first moment at
which (1) every unit's state published since the fault has reached the listener, (2) so have the
coordinator's routes, and (3) after (1) and (2), a state shows a unit on a square other than its
last one, i.e. the fleet moves again on the coordinator's orders; (3) is waived while the stop is
engaged (units stand still by design: the listener sees the latch or a press, or the coordinator's
status says it holds the stop, or every unit's state shows it).

The coordinator may hold a stop nobody engaged: a node it moves to replays an old latch
(RabbitMQ keeps retained messages per node). The soak counts those (`unasked_stops`) and its
operator releases them as one at the hall would; they are no stop the checks hold units to. Live messages only: a retained replay of a node the
listener moved to is no sign of anyone being back.
"""

from __future__ import annotations

import asyncio
import importlib
import os
import time
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, TextIO
from urllib.parse import urlsplit, urlunsplit

from gridfleet.bench.soak.faults import NODE_TARGETS, Fault
from gridfleet.bench.soak.proxy import FaultyProxy
from gridfleet.bench.soak.run import RECOVERY_WAIT_S, Soak, SoakConfig
from gridfleet.config import parse_broker_url
from gridfleet.errors import ConfigError
from gridfleet.ports import PORT_BAND_ENV

# Each kind of cluster: the module of the shipped package that starts it, and its class.
CLUSTERS = {
    "aedes": ("gridfleet.broker.aedes_cluster", "AedesCluster"),
    "rabbitmq": ("gridfleet.broker.rabbitmq_cluster", "RabbitCluster"),
}
SOAK_PORT_BAND = "11"  # gridfleet.ports: make test's workers take 0-9, its soak 10
CLUSTER_UNITS = 30  # units by default on a cluster
# On a cluster, the fleet works between faults: 500 jobs in 30 minutes need it to flow most of
# the time (the plain soak's pacing, a fault every 0.1-0.5 s and a stop every 1-4 s, held it
# most of the time: 24 jobs in 30 minutes).
CLUSTER_FAULT_GAP_S = (4.0, 10.0)
CLUSTER_STOP_GAP_S = (15.0, 30.0)


class BrokerCluster(Protocol):
    """What the soak uses of a cluster (the interface of the test suite's clusters)."""

    @property
    def node_urls(self) -> list[str]:
        """Each node's TCP URL, in order."""
        ...

    @property
    def pids(self) -> list[int]:
        """The process ids of what runs."""
        ...

    def __enter__(self) -> object:
        """Start every node and wait until each takes clients."""

    def __exit__(self, *exc: object) -> None:
        """Stop every node and what they share: nothing of the cluster is left running."""

    def kill_node(self, i: int) -> None:
        """SIGKILL node `i`."""

    def start_node(self, i: int) -> None:
        """Start node `i` again on its ports and wait until it listens."""

    def pause_node(self, i: int) -> None:
        """SIGSTOP node `i`."""

    def resume_node(self, i: int) -> None:
        """SIGCONT node `i`."""


def open_cluster(kind: str, directory: Path) -> BrokerCluster:
    """A cluster of `kind` to run in `directory` (not started)."""
    if kind not in CLUSTERS:
        raise ConfigError(f"--cluster {kind}: give one of {', '.join(CLUSTERS)}")
    module, name = CLUSTERS[kind]
    made: BrokerCluster = getattr(importlib.import_module(module), name)(directory)
    return made


def via_proxy(url: str, port: int, host: str = "127.0.0.1") -> str:
    """`url` (its scheme, login and options) to `host:port` instead of its broker."""
    parts = urlsplit(url)
    login = parts.netloc.rpartition("@")[0]
    netloc = f"{login}@{host}:{port}" if login else f"{host}:{port}"
    return urlunsplit(parts._replace(netloc=netloc))


@dataclass(frozen=True)
class NodeFault:
    """One node fault: its kind, the node, who was on it, and seconds to the fleet moving again."""

    kind: str
    node: int
    on_it: tuple[str, ...]
    took_s: float | None


class ClusterSoak(Soak):
    """The soak's components on a broker cluster, its nodes killed, paused and cut off."""

    RESTARTS_BROKER = False  # no embedded broker: the nodes are what dies
    CLUSTER_FAULTS = True
    LIVE_ONLY = True

    def __init__(
        self,
        cfg: SoakConfig,
        workdir: Path,
        log: TextIO,
        cluster: BrokerCluster | None = None,
    ) -> None:
        super().__init__(cfg, workdir, log)
        assert cfg.cluster is not None
        # A node comes back on the ports it had: ports below the kernel's ephemeral range, where
        # none of the soak's hundred outgoing connections can be holding one meanwhile.
        os.environ.setdefault(PORT_BAND_ENV, SOAK_PORT_BAND)
        self.cluster = cluster or open_cluster(cfg.cluster, workdir / cfg.cluster)
        self.node_urls: list[str] = []
        self.down: set[int] = set()  # nodes killed or paused now
        self.paused: set[int] = set()
        self.lost: set[int] = set()  # nodes that did not start again: no more faults on them
        self.routes: dict[str, list[FaultyProxy]] = {}  # component -> its proxy to each node
        self.node_faults: list[NodeFault] = []

    # ---- the topology's hooks -----------------------------------------------------------

    async def _start_broker(self, logins: list[str]) -> str:
        """Start the cluster (its nodes listening); its nodes' URLs, a list."""
        await asyncio.to_thread(self.cluster.__enter__)
        self.node_urls = list(self.cluster.node_urls)
        print(f"soak: {self.cfg.cluster} cluster, nodes {self.node_urls}", file=self.log)
        return ",".join(self.node_urls)

    async def _links(self) -> dict[str, str]:
        """A proxy per component and node; each component's list begins at another node."""
        urls = {}
        for n, name in enumerate(NODE_TARGETS):
            proxies = []
            for node in self.node_urls:
                target = parse_broker_url(node)
                proxy = FaultyProxy(target.host, target.port, listen=self.listen)
                await proxy.start()
                proxies.append(proxy)
            self.routes[name] = proxies
            self.proxies += proxies
            via = [via_proxy(u, p.port) for u, p in zip(self.node_urls, proxies, strict=True)]
            first = n % len(via)
            urls[name] = ",".join(via[first:] + via[:first])
        return urls

    def _listener_url(self) -> str:
        """The nodes up, beginning at the one after the feed's (node 0 of three)."""
        return self._nodes_up(len(NODE_TARGETS))

    def _login(self, account: str) -> str:
        """The nodes up, directly (the soak's operator and device publish to the first up)."""
        return self._nodes_up(0)

    def _nodes_up(self, first: int) -> str:
        """Every node's URL from node `first` on, round, those down last."""
        count = len(self.node_urls)
        order = [(first + k) % count for k in range(count)]
        order.sort(key=lambda i: i in self.down)  # stable: up first, then down
        return ",".join(self.node_urls[i] for i in order)

    def _close(self) -> None:
        """Stop every node (the components were stopped before), a paused one resumed first."""
        for node in list(self.paused):
            self.cluster.resume_node(node)
        self.cluster.__exit__(None, None, None)

    # ---- the node faults ----------------------------------------------------------------

    def node_of(self, component: str) -> int | None:
        """The node `component` is on now (its proxy with open links), or None (between two)."""
        for node, proxy in enumerate(self.routes.get(component, [])):
            if proxy.open_links:
                return node
        return None

    def on_node(self, node: int) -> tuple[str, ...]:
        """Who is on `node` now: components, and the listener."""
        who = [name for name in NODE_TARGETS if self.node_of(name) == node]
        listener = self.listener
        if listener is not None and listener.on:
            on = parse_broker_url(listener.on)
            mine = parse_broker_url(self.node_urls[node])
            if (on.host, on.port) == (mine.host, mine.port):
                who.append("listener")
        return tuple(who)

    def _reroute(self) -> None:
        """The soak's own clients' lists, the nodes down last."""
        self.operator_url = self._login("operator")
        self.device_url = self._login("device")
        if self.listener is not None:
            self.listener.url = self._listener_url()

    async def _apply(self, fault: Fault) -> None:
        if fault.kind not in ("kill_node", "pause_node", "cut_node"):
            await super()._apply(fault)
            return
        found = self.node_of(fault.target)
        if found is None or found in self.lost:
            spare = [n for n in range(len(self.node_urls)) if n not in self.lost]
            found = self.rng.choice(spare)
        node = found
        on_it = self.on_node(node)
        since = time.time()
        what = f"{fault.kind} {node} ({fault.target}'s) at {since:.2f}"
        if fault.kind == "kill_node":
            self.down.add(node)
            self._reroute()
            await asyncio.to_thread(self.cluster.kill_node, node)
            took = await self._wait_moving(since, what)
            print(f"soak: {what}: moving again after {took} s; starting it", file=self.log)
            try:
                await asyncio.to_thread(self.cluster.start_node, node)
            except Exception as exc:  # the soak goes on without it, and says so
                self.unrecovered.append(f"{what}: not started again: {exc}")
                self.lost.add(node)
            else:
                self.down.discard(node)
                self._reroute()
        else:
            if fault.kind == "pause_node":
                self.down.add(node)
                self._reroute()
                self.cluster.pause_node(node)
                self.paused.add(node)
            else:
                for proxy in self._proxies_to(node):
                    proxy.refusing = True
                    proxy.cut()
            moving = asyncio.create_task(self._wait_moving(since, what))
            try:
                await asyncio.sleep(fault.hold_s)  # the fault itself: the node away this long
            finally:
                if fault.kind == "pause_node":
                    self.cluster.resume_node(node)
                    self.paused.discard(node)
                    self.down.discard(node)
                    self._reroute()
                else:
                    for proxy in self._proxies_to(node):
                        proxy.refusing = False
            took = await moving
        self.node_faults.append(NodeFault(fault.kind, node, on_it, took))
        shown = "not" if took is None else f"{took:.2f} s"
        print(f"[node       ] {what}, on it: {', '.join(on_it) or 'none'}; moving: {shown}",
              file=self.log)  # fmt: skip

    def _proxies_to(self, node: int) -> list[FaultyProxy]:
        return [proxies[node] for proxies in self.routes.values()]

    async def _wait_moving(self, since: float, what: str) -> float | None:
        """Seconds from `since` to the fleet moving again (the module's definition), or None
        (and reported) after RECOVERY_WAIT_S."""
        listener = self.listener
        assert listener is not None
        deadline = time.monotonic() + RECOVERY_WAIT_S
        back: float | None = None  # when every unit's state and the routes came since `since`
        while time.monotonic() < deadline:
            now = time.time()
            if back is None:
                late = [u for u in self.unit_ids if listener.last_state.get(u, 0.0) <= since]
                if not late and listener.last_routes > since:
                    back = now
            held = listener.held or all(listener.estop_shown.get(u) for u in self.unit_ids)
            if back is not None and (held or listener.last_move > back):
                return now - since
            await asyncio.sleep(0.05)  # polling the listener, with a deadline
        late = [u for u in self.unit_ids if listener.last_state.get(u, 0.0) <= since]
        missing = [f"no state from {', '.join(late)}"] if late else []
        if listener.last_routes <= since:
            missing.append("no routes from the coordinator")
        if back is not None:
            missing.append("every unit back, none moved")
        self.unrecovered.append(f"{what}: after {RECOVERY_WAIT_S:.0f} s, {'; '.join(missing)}")
        return None

    def _held(self) -> bool:
        """Stopped, or held by the coordinator (a stop nobody engaged): the operator releases."""
        assert self.listener is not None
        return self.listener.held

    def _extra(self) -> dict[str, object]:
        """Stops the coordinator held that nobody engaged, and where each fault left who."""
        assert self.listener is not None
        unrecovered = Counter(f.kind for f in self.node_faults if f.took_s is None)
        return {
            "unasked_stops": len(self.listener.unasked_stops),
            # Node faults the fleet did not move again within RECOVERY_WAIT_S of (not in the
            # figures of node_recovery_s: their time is unknown, past the wait).
            "node_unrecovered": dict(sorted(unrecovered.items())),
            "node_faults": [
                {"kind": f.kind, "node": f.node, "on_it": list(f.on_it), "took_s": f.took_s}
                for f in self.node_faults
            ],
        }

    def _node_recoveries(self) -> dict[str, list[float]]:
        """Per node fault's kind, the seconds to the fleet moving again."""
        took: defaultdict[str, list[float]] = defaultdict(list)
        for fault in self.node_faults:
            if fault.took_s is not None:
                took[fault.kind].append(fault.took_s)
        return dict(took)
