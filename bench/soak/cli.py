"""`gridfleet bench soak`: the chaos soak from the command line."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import sys
from pathlib import Path

from gridfleet.bench.lan import can_make_lans
from gridfleet.bench.soak.cluster import (
    CLUSTER_FAULT_GAP_S,
    CLUSTER_STOP_GAP_S,
    CLUSTER_UNITS,
    CLUSTERS,
)
from gridfleet.bench.soak.faults import (
    CLUSTER_DEFAULT,
    CLUSTER_FAMILIES,
    FAMILIES,
    LOCAL_FAMILIES,
    NETWORK_FAMILIES,
    parse_families,
)
from gridfleet.bench.soak.run import MOSQUITTO, RECOVERY_WAIT_S, SoakConfig, SoakResult
from gridfleet.bench.soak.topologies import run_soak
from gridfleet.config import check_step, parse_brokers, redacted
from gridfleet.errors import ConfigError


def families(text: str) -> tuple[str, ...]:
    """argparse type of --faults."""
    try:
        return tuple(parse_families(text))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"{exc} (known: {','.join(FAMILIES)})") from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench soak`."""
    parser.add_argument("--minutes", type=float, default=5.0, help="minutes of faults (default 5)")
    parser.add_argument(
        "--units", type=int, default=None, help=f"units (default 12; {CLUSTER_UNITS} on a cluster)"
    )
    parser.add_argument("--seed", type=int, default=0, help="fault schedule and extra units")
    parser.add_argument("--step", type=float, default=0.1, help="step period, s (default 0.1)")
    parser.add_argument(
        "--broker",
        help="an external broker, one URL: its proxy stands in front of it (default: an "
        "embedded one, restarted as a fault)",
    )
    parser.add_argument(
        "--faults",
        type=families,
        default=None,
        help=f"fault families to inject (default all: {','.join(LOCAL_FAMILIES)}, and with "
        f"--network {','.join(NETWORK_FAMILIES)}; with --cluster {','.join(CLUSTER_DEFAULT)})",
    )
    parser.add_argument(
        "--cluster",
        choices=sorted(CLUSTERS),
        help="run on a broker cluster the soak starts on loopback (aedes instances on one Redis, "
        "or three RabbitMQ nodes), each component's broker list beginning at another node; adds "
        "node faults (one killed and started again, paused, cut off from its clients) and says "
        "how long the fleet took to move again after each (median, p99, worst)",
    )
    parser.add_argument(
        "--network",
        action="store_true",
        help="the units and the coordinator on hosts of their own (network namespaces on one "
        "bridge; needs root), the broker on this machine's LAN address with accounts; adds "
        "silent link cuts, stalls and thin lossy links to the faults",
    )
    parser.add_argument(
        "--bridge",
        action="store_true",
        help="with --network: the units on a hall's Mosquitto of their own, bridged through the "
        "proxy to a central Mosquitto (coordinator, soak): the hall's link faults and the "
        "proxy's cuts and delays are the bridge's; no broker restarts",
    )
    parser.add_argument(
        "--drain", type=float, default=90.0, help="seconds for jobs to end after the faults"
    )
    parser.add_argument(
        "--stranded", type=float, default=30.0, help="undisturbed seconds a busy unit may stand"
    )
    parser.add_argument("--verbose", action="store_true", help="the components' log on stderr")
    parser.add_argument(
        "--log", metavar="FILE", help="the components' log (and a stall's evidence) into FILE"
    )
    parser.add_argument(
        "--keep",
        metavar="DIR",
        type=Path,
        help="run in DIR and leave its job store, units' state and ground truth there",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def config(args: argparse.Namespace) -> SoakConfig:
    """The run the flags describe; one clear line (ConfigError) for each bad flag."""
    if not args.minutes > 0:
        raise ConfigError(f"--minutes {args.minutes}: give a positive number of minutes")
    units = args.units if args.units is not None else CLUSTER_UNITS if args.cluster else 12
    if units < 1:
        raise ConfigError(f"--units {units}: give at least 1")
    check_step(args.step)
    if args.broker is not None and len(parse_brokers(args.broker)) > 1:
        raise ConfigError(
            f"--broker {redacted(args.broker)}: one broker, not a list (the soak's proxy "
            "stands in front of one)"
        )
    everything = tuple(f for f in FAMILIES if f not in CLUSTER_FAMILIES)
    faults = args.faults or (
        CLUSTER_DEFAULT if args.cluster else everything if args.network else LOCAL_FAMILIES
    )
    if args.cluster and (args.broker is not None or args.network):
        raise ConfigError(f"--cluster {args.cluster} runs its own nodes: no --broker, no --network")
    if set(faults) & set(CLUSTER_FAMILIES) and not args.cluster:
        raise ConfigError(f"--faults {','.join(CLUSTER_FAMILIES)} need --cluster")
    if args.network:
        if args.broker is not None:
            raise ConfigError(
                "--network runs its own broker, on the LAN with accounts: no --broker"
            )
        why_not = can_make_lans()
        if why_not is not None:
            raise ConfigError(f"--network: {why_not}")
        if args.bridge and not Path(MOSQUITTO).exists():
            raise ConfigError("--bridge runs Mosquitto: install it (apt-get install mosquitto)")
    elif args.bridge:
        raise ConfigError("--bridge bridges the hosts of a LAN: give --network too")
    elif set(faults) & set(NETWORK_FAMILIES):
        raise ConfigError(f"--faults {','.join(NETWORK_FAMILIES)} need --network")
    return SoakConfig(
        minutes=args.minutes,
        units=units,
        seed=args.seed,
        broker=args.broker,
        step_s=args.step,
        faults=faults,
        network=args.network,
        bridge=args.bridge,
        drain_s=args.drain,
        stranded_s=args.stranded,
        cluster=args.cluster,
        # On a cluster the fleet works between faults: its jobs are part of the figures.
        fault_gap_s=CLUSTER_FAULT_GAP_S if args.cluster else SoakConfig.fault_gap_s,
        stop_gap_s=CLUSTER_STOP_GAP_S if args.cluster else SoakConfig.stop_gap_s,
        keep_active=units if args.cluster else None,
    )


def print_result(result: SoakResult) -> None:
    """A few lines for people."""
    out = result.as_json()
    faults = ", ".join(f"{k} {v}" for k, v in out["faults"].items())
    print(f"soak: {out['minutes']} min, {out['units']} units; faults: {faults or 'none'}")
    for key in (
        "collisions", "moved_while_stopped", "jobs_submitted", "jobs_done", "jobs_lost",
        "jobs_duplicated", "units_stranded", "faults_unrecovered", "max_recovery_s",
    ):  # fmt: skip
        print(f"  {key:<20} {out[key]}")
    if out["cluster"] is not None:
        print(f"  {'unasked_stops':<20} {out['unasked_stops']}")
        print(f"  on a {out['cluster']} cluster: from a node fault to the fleet moving again:")
        for kind, took in out["node_recovery_s"].items():
            print(
                f"    {kind:<10} {took['n']:>4} times: median {took['median']} s, "
                f"p99 {took['p99']} s, worst {took['max']} s"
            )
        for kind, count in out["node_unrecovered"].items():
            print(f"    {kind:<10} {count:>4} times not within {RECOVERY_WAIT_S:g} s")
    if out["worst_stop_to_hall_s"] is not None:  # --bridge: the stop across the bridge
        print(
            f"  the stop reached the hall's broker {out['worst_stop_to_hall_s']} s late at worst;"
        )
        print(f"  moves before it had it: {out['moved_before_the_hall_had_the_stop']}")
    for line in out["details"]:
        print(f"  ! {line}")
    print("OK" if result.ok else "FAILED")


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet bench soak`: exit 1 when a check fails."""
    cfg = config(args)
    logging.disable(logging.WARNING)  # the figures are the output; faults make components warn
    where = args.log or os.devnull
    with open(where, "w", encoding="utf-8", buffering=1) as log:
        result = asyncio.run(run_soak(cfg, sys.stderr if args.verbose else log, args.keep))
    if args.json:
        json.dump(result.as_json(), sys.stdout)
        sys.stdout.write("\n")
    else:
        print_result(result)
    return 0 if result.ok else 1
