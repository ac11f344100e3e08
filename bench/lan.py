"""A LAN made of network namespaces on this machine: hosts on one bridge, links to cut and stall.

For the tests (tests/support/lan.py) and `gridfleet bench soak --network`.

Each host is a namespace of its own with one interface (`eth0`) plugged into a bridge that lives
in a namespace of its own too. The first host, `here`, stands for the machine running the broker,
the coordinator and whoever watches: a thread of this process enters it with `Lan.call` (sockets
it makes, and threads it starts, are on the LAN) and a command runs there with `Lan.command`.
Nothing is made in this machine's own namespace: a new address there makes Chromium drop the
requests it has in flight (ERR_NETWORK_CHANGED; a page in another test stopped loading). Made
with `ip` and `tc` as root and removed again, also when its user fails (and what a killed run
left is swept up by the next one: the names carry the process id).

Faults, per host:
- `cut`: its bridge port goes down. Nothing is sent, nothing is closed (no FIN, no RST): the
  other side learns of it only from a keep-alive, as with a switch port that dies.
- `stall`: every packet either way is dropped (a `tbf` qdisc too small for any packet) while
  both ends stay up, as with a Wi-Fi link that hangs.
- `narrow`: a thin link (a `tbf` rate limit): slow, and what queues too long is dropped.
- `heal`: all undone.
"""

from __future__ import annotations

import ctypes
import ipaddress
import os
import random
import re
import shutil
import subprocess
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TypeVar

T = TypeVar("T")

HERE = "here"  # the first host: the broker's machine
PREFIX = "gfl"  # every namespace made here: gfl<pid>-... (swept once <pid> is gone)
SUBNETS = ipaddress.IPv4Network("10.231.0.0/16")
DROP_ALL = ["tbf", "rate", "8bit", "burst", "1", "limit", "1"]  # no packet fits: all dropped


class LanError(RuntimeError):
    """An `ip` or `tc` command failed (the kernel lacks namespaces, veth or tbf)."""


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    done = subprocess.run(["ip", *args], capture_output=True, text=True, check=False)
    if check and done.returncode != 0:
        raise LanError(f"ip {' '.join(args)}: {done.stderr.strip()}")
    return done


def _tc(netns: str, *args: str, check: bool = True) -> None:
    done = subprocess.run(["tc", "-n", netns, *args], capture_output=True, text=True, check=False)
    if check and done.returncode != 0:
        raise LanError(f"tc -n {netns} {' '.join(args)}: {done.stderr.strip()}")


@dataclass
class Host:
    """One machine on the LAN: a namespace with `eth0` on the bridge, at `address`."""

    name: str
    netns: str
    address: str
    port: str  # its bridge port, in the LAN's namespace
    lan: Lan

    def command(self, argv: Sequence[str]) -> list[str]:
        """`argv` run on this host."""
        return ["ip", "netns", "exec", self.netns, *argv]

    def cut(self) -> None:
        """Unplug it at the bridge: nothing more arrives either way, and nobody is told."""
        _ip("-n", self.lan.netns, "link", "set", self.port, "down")

    def stall(self) -> None:
        """Drop every packet either way, both ends staying up."""
        _tc(self.netns, "qdisc", "replace", "dev", "eth0", "root", *DROP_ALL)
        _tc(self.lan.netns, "qdisc", "replace", "dev", self.port, "root", *DROP_ALL)

    def narrow(self, kbit: int) -> None:
        """Limit its link to `kbit` kbit/s either way; what queues past 50 ms is dropped (loss)."""
        shape = ["tbf", "rate", f"{kbit}kbit", "burst", "1600", "latency", "50ms"]
        _tc(self.netns, "qdisc", "replace", "dev", "eth0", "root", *shape)
        _tc(self.lan.netns, "qdisc", "replace", "dev", self.port, "root", *shape)

    def heal(self) -> None:
        """Plugged in again, nothing dropped."""
        _tc(self.netns, "qdisc", "del", "dev", "eth0", "root", check=False)
        _tc(self.lan.netns, "qdisc", "del", "dev", self.port, "root", check=False)
        _ip("-n", self.lan.netns, "link", "set", self.port, "up")


@dataclass
class Lan:
    """The bridge, its first host `here` (the broker's machine), and the hosts added with `host`."""

    tag: str
    short: str  # six hex digits naming this LAN's interfaces
    netns: str
    network: ipaddress.IPv4Network
    hosts: dict[str, Host] = field(default_factory=dict)

    @property
    def here(self) -> Host:
        """The broker's machine on the LAN."""
        return self.hosts[HERE]

    @property
    def address(self) -> str:
        """`here`'s address: where the LAN's hosts reach the broker."""
        return self.here.address

    def command(self, argv: Sequence[str]) -> list[str]:
        """`argv` run on `here`."""
        return self.here.command(argv)

    def call(self, work: Callable[[], T]) -> T:
        """`work()` run by a thread of this process on `here`: what it connects, binds or starts
        (threads included) is on the LAN. Its result, or its exception."""
        done: Future[T] = Future()

        def run() -> None:
            try:
                _enter(self.here.netns)
                done.set_result(work())
            except BaseException as exc:  # handed to the caller
                done.set_exception(exc)

        thread = threading.Thread(target=run, name=f"on {self.here.netns}", daemon=True)
        thread.start()
        return done.result()

    def enter(self) -> None:
        """Put the calling thread on `here` for good (a process that lives on the LAN)."""
        _enter(self.here.netns)

    def host(self, name: str) -> Host:
        """A new host on the LAN (a namespace with its own address), called `name` here."""
        if not re.fullmatch(r"[a-z0-9]{1,6}", name) or name in self.hosts:
            raise ValueError(f"host name {name!r}: 1-6 lowercase letters or digits, not taken")
        number = len(self.hosts) + 1
        netns = f"{self.tag}-{name}"
        # Interface names hold 15 characters: the LAN's short id and the host's number.
        port = f"gf{self.short}{number}p"
        address = str(self.network.network_address + number)
        _ip("netns", "add", netns)
        host = Host(name, netns, address, port, self)
        self.hosts[name] = host
        # Made in the host's namespace with its peer in the LAN's: never in this machine's.
        _ip("-n", netns, "link", "add", "eth0", "type", "veth", "peer", "name", port, "netns",
            self.netns)  # fmt: skip
        _ip("-n", self.netns, "link", "set", port, "master", "br0", "up")
        _ip("-n", netns, "addr", "add", f"{address}/{self.network.prefixlen}", "dev", "eth0")
        _ip("-n", netns, "link", "set", "eth0", "up")
        _ip("-n", netns, "link", "set", "lo", "up")
        return host


_CLONE_NEWNET = 0x40000000
_libc = ctypes.CDLL(None, use_errno=True)


def _enter(netns: str) -> None:
    """Move the calling thread into network namespace `netns` (setns(2))."""
    fd = os.open(f"/run/netns/{netns}", os.O_RDONLY)
    try:
        if _libc.setns(fd, _CLONE_NEWNET) != 0:
            raise LanError(f"setns {netns}: {os.strerror(ctypes.get_errno())}")
    finally:
        os.close(fd)


def _sweep() -> None:
    """Remove what killed runs left: namespaces named for a process that is gone."""
    for netns in _ip("netns", "list", check=False).stdout.split():
        made = re.fullmatch(rf"{PREFIX}(\d+)-[0-9a-f]+-\w+", netns)
        if made and not os.path.exists(f"/proc/{made[1]}"):
            _ip("netns", "del", netns, check=False)


def can_make_lans() -> str | None:
    """Why this machine cannot make a test LAN, or None when it can."""
    if os.geteuid() != 0:
        return "network namespaces need root"
    missing = [tool for tool in ("ip", "tc") if shutil.which(tool) is None]
    return f"{' and '.join(missing)} not installed (iproute2)" if missing else None


@contextmanager
def lan() -> Iterator[Lan]:
    """A LAN, its host `here` made, removed afterwards whatever happened."""
    _sweep()
    short = os.urandom(3).hex()
    tag = f"{PREFIX}{os.getpid()}-{short}"
    network = SUBNETS.subnets(new_prefix=24)
    # A subnet of its own: two LANs of one machine are apart anyway, but a host's address reads
    # better unique in a log.
    made = Lan(tag, short, f"{tag}-lan", random.choice(list(network)))
    try:
        _ip("netns", "add", made.netns)
        _ip("-n", made.netns, "link", "add", "br0", "type", "bridge")
        _ip("-n", made.netns, "link", "set", "br0", "up")
        made.host(HERE)
        yield made
    finally:
        for host in made.hosts.values():
            _ip("netns", "del", host.netns, check=False)
        _ip("netns", "del", made.netns, check=False)  # takes the bridge with it
