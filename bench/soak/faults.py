"""The soak's fault schedule: which fault comes next and for how long, drawn from a seeded RNG."""

from __future__ import annotations

import random
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

# Families the CLI's --faults selects from; each gives one or more counted kinds.
FAMILIES = (
    "units", "coordinator", "broker", "pause", "cut", "delay", "estop", "press",
    "silent", "stall", "narrow", "node", "node_pause", "node_cut",
)  # fmt: skip
STOP_FAMILIES = ("estop", "press")  # the stop lane; the rest are the main lane's
# Only with --network (the units and the coordinator on hosts of a LAN of namespaces): a host's
# link cut without a word, every packet dropped with both ends up, or a thin lossy link.
NETWORK_FAMILIES = ("silent", "stall", "narrow")
# Only with --cluster: one broker node killed (SIGKILL, then started again), paused (SIGSTOP …
# SIGCONT) or cut off from the fleet's clients, the node that one component is on.
CLUSTER_FAMILIES = ("node", "node_pause", "node_cut")
LOCAL_FAMILIES = tuple(f for f in FAMILIES if f not in NETWORK_FAMILIES + CLUSTER_FAMILIES)
# On a cluster: the local families but the embedded broker's restart, and the node faults.
CLUSTER_DEFAULT = tuple(f for f in LOCAL_FAMILIES if f != "broker") + CLUSTER_FAMILIES
# The components whose broker node a node fault strikes: the coordinator, the units process, the
# feed (the supervisor's name for it: operator).
NODE_TARGETS = ("coordinator", "robots", "operator")
# A node's death is what a cluster soak measures (median, p99, worst): three in each round.
PER_ROUND = {"node": 3}
NETWORK_HOSTS = ("units", "office")  # the robots' host, the coordinator's
# With a bridge the robots' host is a hall with a broker of its own: its link is the bridge's.
BRIDGED_HOSTS = ("hall", "office")
KEEP_ALIVE_S = 10.0  # gridfleet's clients: the broker gives up on a silent one after 1.5 of it
LONG_SILENCE_SHARE = 0.2  # of the silent cuts, longer than the broker's keep-alive
# How far past 1.5 keep-alives a long cut lasts, for the will to come within it: the embedded
# broker sends it on time; Mosquitto looks at keep-alives every few seconds (up to 21 s measured,
# and 16-18.7 s cuts missed it in a bridge soak).
WILL_SLACK_S = (1.0, 5.0)
MOSQUITTO_WILL_SLACK_S = (8.0, 12.0)
KBITS = (32, 64, 128, 256)  # `narrow`: a poor Wi-Fi link's rates (a state is ~0.5 kB)


@dataclass(frozen=True)
class Fault:
    """One fault: its counted kind, what it hits, how long it lasts, and a latency for `delay`."""

    kind: str  # e.g. kill_broker, term_units, pause_coordinator, cut, delay, estop_operator
    target: str = ""  # the process: broker, coordinator or robots
    hold_s: float = 0.0  # paused, link down, slowed or stop held this long
    latency_s: float = 0.0
    kbit: int = 0  # `narrow`: the link's rate


def main_faults(
    rng: random.Random,
    families: Sequence[str],
    step_s: float,
    hosts: Sequence[str] = NETWORK_HOSTS,
    will_slack_s: tuple[float, float] = WILL_SLACK_S,
) -> Iterator[Fault]:
    """Process and link faults for ever: every selected family once per round (a node's death
    PER_ROUND times), in seeded order; the network's on one of `hosts` at random."""
    staleness = 5 * step_s  # the coordinator's and units' staleness timeout
    chosen = [f for f in FAMILIES if f in families and f not in STOP_FAMILIES]
    while chosen:
        order = [f for f in chosen for _ in range(PER_ROUND.get(f, 1))]
        rng.shuffle(order)
        for family in order:
            if family in ("units", "coordinator", "broker"):
                how = rng.choice(("kill", "term"))
                yield Fault(f"{how}_{family}", "robots" if family == "units" else family)
            elif family == "pause":
                target = rng.choice(("robots", "coordinator"))
                name = "units" if target == "robots" else target
                # Past the staleness timeout, or the pause tests nothing.
                hold = rng.uniform(staleness + 0.5, staleness + 2.5)
                yield Fault(f"pause_{name}", target, hold)
            elif family == "cut":
                yield Fault("cut", hold_s=rng.uniform(0.0, 1.0))
            elif family == "delay":
                yield Fault("delay", hold_s=rng.uniform(1.0, 3.0), latency_s=rng.uniform(0.05, 0.5))
            elif family in CLUSTER_FAMILIES:
                yield _node_fault(rng, family)
            elif family == "silent":
                host = rng.choice(hosts)
                if rng.random() < LONG_SILENCE_SHARE:  # past the keep-alive: the will is sent
                    least, most = will_slack_s
                    hold = rng.uniform(1.5 * KEEP_ALIVE_S + least, 1.5 * KEEP_ALIVE_S + most)
                    yield Fault(f"silent_long_{host}", host, hold)
                else:
                    yield Fault(f"silent_{host}", host, rng.uniform(0.5, 4.0))
            elif family == "stall":
                host = rng.choice(hosts)
                yield Fault(f"stall_{host}", host, rng.uniform(0.5, 5.0))
            elif family == "narrow":
                host = rng.choice(hosts)
                yield Fault(f"narrow_{host}", host, rng.uniform(1.0, 5.0), kbit=rng.choice(KBITS))


def _node_fault(rng: random.Random, family: str) -> Fault:
    """A node fault on the node one of NODE_TARGETS is on: killed, paused (some past the
    clients' keep-alive, so that they give up on it and move to the next node) or cut off."""
    target = rng.choice(NODE_TARGETS)
    if family == "node":
        return Fault("kill_node", target)
    if family == "node_pause":
        if rng.random() < LONG_SILENCE_SHARE:
            least, most = WILL_SLACK_S
            hold = rng.uniform(1.5 * KEEP_ALIVE_S + least, 1.5 * KEEP_ALIVE_S + most)
        else:
            hold = rng.uniform(1.0, 5.0)
        return Fault("pause_node", target, hold)
    return Fault("cut_node", target, rng.uniform(0.5, 5.0))


def stop_faults(rng: random.Random, families: Sequence[str]) -> Iterator[Fault]:
    """Stops engaged and released for ever, from an operator or a device, alternating at random."""
    chosen = [f for f in STOP_FAMILIES if f in families]
    while chosen:
        family = rng.choice(chosen)
        kind = "estop_operator" if family == "estop" else "estop_device"
        yield Fault(kind, hold_s=rng.uniform(1.0, 4.0))


def parse_families(text: str) -> list[str]:
    """`units,cut` → ['units', 'cut']; ValueError naming an unknown family."""
    families = [f.strip() for f in text.split(",") if f.strip()]
    unknown = [f for f in families if f not in FAMILIES]
    if unknown or not families:
        raise ValueError(f"unknown fault {unknown[0]!r}" if unknown else "give at least one fault")
    return families
