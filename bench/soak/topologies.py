"""Where a soak's parts run: three topologies of one `Soak`, and `run_soak`, which picks one.

`PlainSoak`: every client on loopback, through the proxy. `NetworkSoak` (`network`): the units and
the coordinator on hosts of their own (network namespaces on one bridge, `gridfleet.bench.lan`),
reaching the broker at this machine's LAN address with accounts, and the main lane also cuts a
host's link without a word (some cuts past the broker's keep-alive: the will must come), stalls it,
or narrows it to a thin, lossy link. `BridgeSoak` (`bridge` as well): the units' host is a hall
with a Mosquitto of its own, bridged to a central Mosquitto (the coordinator's, the soak's) through
the proxy: every fault of the hall's link and of the proxy is then a bridge's.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import shlex
import socket
import tempfile
import time
from pathlib import Path
from typing import TextIO

from gridfleet.accounts import Account, Accounts, default_accounts, new_password, write_accounts
from gridfleet.bench.lan import lan
from gridfleet.bench.soak.check import Stop
from gridfleet.bench.soak.cluster import ClusterSoak
from gridfleet.bench.soak.faults import BRIDGED_HOSTS, MOSQUITTO_WILL_SLACK_S
from gridfleet.bench.soak.run import (
    DEVICE,
    HALL,
    MOSQUITTO,
    MOSQUITTO_SUB,
    Soak,
    SoakConfig,
    SoakResult,
    hall_stops,
)
from gridfleet.broker.mosquitto import bridge_conf, mosquitto_conf, write_files
from gridfleet.config import with_credentials
from gridfleet.ports import free_port
from gridfleet.protocol.stop import stop_filters
from gridfleet.system.supervisor import ChildSpec


class PlainSoak(Soak):
    """Every client on loopback, through the proxy; the broker embedded (restarted) or given."""


class NetworkSoak(Soak):
    """The units and the coordinator on hosts of a LAN of namespaces (root), the broker on this
    machine's LAN address with accounts; the network's faults (cut, stall, narrow) strike too."""

    NETWORK_FAULTS = True
    UNITS_HOST = "units"  # the host the units process runs on

    def __init__(self, cfg: SoakConfig, workdir: Path, log: TextIO) -> None:
        super().__init__(cfg, workdir, log)
        self.lan = contextlib.ExitStack()  # the LAN: removed at the end

    def _open(self) -> list[str]:
        """The LAN and its hosts, and the accounts a broker beyond loopback needs; the flags that
        log each component in."""
        net = self.lan.enter_context(lan())
        self.hosts = {name: net.host(name) for name in self.FAULT_HOSTS}
        # The soak itself (its broker, proxy, listener, operator and feed) lives on the LAN's
        # first host from now on: the threads and processes it starts follow it there.
        net.enter()
        self.accounts = self._accounts()
        accounts_file = self.dir / "accounts.toml"
        write_accounts(self.accounts, accounts_file)
        print(f"soak: LAN {net.network}, hosts {self.hosts}", file=self.log)
        self.listen = net.address
        return ["--accounts", str(accounts_file)]

    def _accounts(self) -> Accounts:
        """Every unit's, the operator's and the soak's device's account."""
        device = Account(DEVICE, new_password(), "device", self.unit_ids[0])
        return default_accounts(self.unit_ids).with_account(device)

    def _coordinator_broker(self, via: str) -> str:
        """The coordinator's host reaches the broker directly (the units' through the proxy)."""
        return self.broker_url

    def _place(self, coordinator: list[str], robots: list[str]) -> tuple[list[str], list[str]]:
        """The coordinator on the office's host, the units on theirs."""
        office, units = self.hosts["office"], self.hosts[self.UNITS_HOST]
        return office.command(coordinator), units.command(robots)

    def _login(self, account: str) -> str:
        """The broker's URL logging in as `account`."""
        return with_credentials(self.broker_url, account, self.accounts.get(account).password)

    def _client_id(self, what: str, device: bool = False) -> str:
        """A client id of the soak's own, one its account owns."""
        return f"{DEVICE if device else 'operator'}-{self.root}-{what}"

    def _close(self) -> None:
        """Remove the LAN."""
        self.lan.close()


class BridgeSoak(NetworkSoak):
    """The units on a hall's Mosquitto bridged to a central Mosquitto through the proxy (no broker
    restarts: Mosquitto keeps the latch only as often as it saves)."""

    FAULT_HOSTS = BRIDGED_HOSTS
    WILL_SLACK = MOSQUITTO_WILL_SLACK_S
    RESTARTS_BROKER = False
    UNITS_HOST = "hall"

    def __init__(self, cfg: SoakConfig, workdir: Path, log: TextIO) -> None:
        super().__init__(cfg, workdir, log)
        self.hall_watch = workdir / "hall-stop.txt"  # the stop at the hall

    def _accounts(self) -> Accounts:
        """The network's accounts and the hall broker's bridge account."""
        return super()._accounts().with_account(Account(HALL, new_password(), "bridge"))

    async def _start_broker(self, logins: list[str]) -> str:
        """The central Mosquitto (accounts, on the LAN's first host), listening; its URL."""
        listen = self.listen
        directory = self.dir / "central"
        passwd, acl = write_files(self.accounts, self.topics, directory)
        port = free_port()
        conf = mosquitto_conf(passwd, acl, host=listen, port=port, ws_port=None)
        self.children["broker"] = await self.sup.start(
            ChildSpec("broker", [MOSQUITTO, "-c", str(_conf_file(directory, conf))])
        )
        deadline = time.monotonic() + 10.0
        while not _connects(listen, port):
            if time.monotonic() > deadline:
                raise RuntimeError(f"the central mosquitto is not listening on {listen}:{port}")
            await asyncio.sleep(0.05)  # polling its port, with a deadline
        return f"mqtt://{listen}:{port}"

    async def _units_broker(self, proxy_port: int) -> str:
        """The hall's Mosquitto on its host, bridged to the central one through the proxy; the
        URL its units reach it at (its loopback: only the bridge crosses the hall's link)."""
        directory = self.dir / "hall"
        passwd, acl = write_files(self.accounts, self.topics, directory)
        port = free_port()
        bridge = bridge_conf(self.accounts.get(HALL), self.listen, proxy_port, self.topics)
        conf = mosquitto_conf(passwd, acl, host="127.0.0.1", port=port, ws_port=None) + bridge
        argv = self.hosts["hall"].command([MOSQUITTO, "-c", str(_conf_file(directory, conf))])
        self.children["hall"] = await self.sup.start(ChildSpec("hall", argv))
        # What the hall's broker has of the stop, when: its units cannot know it sooner. One
        # line a message, "<unix time> <topic> <payload>", read after the run (hall_stops).
        operator = self.accounts.get("operator")
        watch = [MOSQUITTO_SUB, "-h", "127.0.0.1", "-p", str(port), "-u", "operator"]
        watch += ["-P", operator.password, "-i", self._client_id("hall-watch"), "-q", "1"]
        watch += ["-F", "%U %t %p", "-k", "10"]
        for topic, _ in stop_filters(self.topics):
            watch += ["-t", topic]
        script = f"exec {shlex.join(watch)} >> {shlex.quote(str(self.hall_watch))}"
        argv = self.hosts["hall"].command(["sh", "-c", script])
        self.children["hall-watch"] = await self.sup.start(ChildSpec("hall-watch", argv))
        return f"mqtt://127.0.0.1:{port}"  # the units wait for it: they retry until it listens

    def _hall_stops(self) -> list[Stop]:
        """The stop as the hall's broker had it, from its watcher's lines."""
        return hall_stops(self.hall_watch, self.topics)


def soak_for(cfg: SoakConfig, workdir: Path, log: TextIO) -> Soak:
    """The soak of `cfg`'s topology: on loopback, on a LAN, with a hall's bridge, or on a broker
    cluster."""
    if cfg.cluster is not None:
        return ClusterSoak(cfg, workdir, log)
    if cfg.bridge:
        return BridgeSoak(cfg, workdir, log)
    if cfg.network:
        return NetworkSoak(cfg, workdir, log)
    return PlainSoak(cfg, workdir, log)


async def run_soak(cfg: SoakConfig, log: TextIO, keep: Path | None = None) -> SoakResult:
    """One soak run in a temporary directory of its own, or in `keep` (left for a post-mortem)."""
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        return await soak_for(cfg, keep, log).run()
    with tempfile.TemporaryDirectory(prefix="gridfleet-soak-") as tmp:
        return await soak_for(cfg, Path(tmp), log).run()


def _conf_file(directory: Path, conf: str) -> Path:
    """`conf` written as `directory/mosquitto.conf`."""
    # Started as root, Mosquitto reads its files as user mosquitto unless told to stay root (the
    # accounts' files are the owner's only).
    path = directory / "mosquitto.conf"
    path.write_text(conf + ("user root\n" if os.geteuid() == 0 else ""))
    return path


def _connects(host: str, port: int) -> bool:
    """Whether a TCP connection to `host:port` is taken."""
    with socket.socket() as probe:
        return probe.connect_ex((host, port)) == 0
