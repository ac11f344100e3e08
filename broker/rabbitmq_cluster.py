"""A three-node RabbitMQ 3.10 cluster on one machine: Debian's rabbitmq-server with its MQTT and
web MQTT plugins, every node on free loopback ports, with its own Erlang port mapper (epmd) and
cookie, everything in a folder of its own; no system service is used (the test suite's broker kind
`rabbitmq`, `gridfleet bench soak --cluster rabbitmq`)."""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import struct
import subprocess
import time
from contextlib import suppress
from pathlib import Path

from gridfleet.broker.cluster_nodes import ClusterError, NodeList, wait_until
from gridfleet.broker.rabbitmq import rabbitmq_conf
from gridfleet.ports import free_port

SBIN = Path("/usr/lib/rabbitmq/lib/rabbitmq_server-3.10.8/sbin")
EPMD = "/usr/bin/epmd"
PLUGINS = "[rabbitmq_mqtt,rabbitmq_web_mqtt].\n"
# Three nodes booting at once on two shared cores take 20-30 s; a node that comes back alone, ~10.
START_TIMEOUT_S = 120.0


def _mqtt_connack(port: int, client_id: str, login: tuple[str, str] | None) -> int | None:
    """The return code of an MQTT 3.1.1 CONNECT to loopback `port` (None: no answer)."""
    flags = 0x02  # clean session
    payload = struct.pack("!H", len(client_id)) + client_id.encode()
    if login is not None:
        flags |= 0xC0
        for field in login:
            payload += struct.pack("!H", len(field.encode())) + field.encode()
    variable = b"\x00\x04MQTT\x04" + bytes([flags]) + struct.pack("!H", 30)
    body = variable + payload
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=5) as link:
            link.sendall(bytes([0x10, len(body)]) + body)  # short: one length byte
            answer = link.recv(4)
            if len(answer) == 4 and answer[0] == 0x20:
                link.sendall(b"\xe0\x00")  # DISCONNECT
                return answer[3]
    except OSError:
        return None
    return None


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _beam_of(wrapper: subprocess.Popen[bytes]) -> int | None:
    """The Erlang VM (beam.smp) the rabbitmq-server script started, once it runs: a process
    below the script (which runs other commands first) named beam.smp."""
    below = _children(wrapper.pid)
    while below:
        pid = below.pop()
        try:
            name = Path(f"/proc/{pid}/comm").read_text().strip()
        except OSError:
            continue
        if name.startswith("beam"):
            return pid
        below += _children(pid)
    return None


def _alive(pid: int) -> bool:
    """Whether process `pid` exists and is not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


class RabbitCluster(NodeList):
    """Three clustered RabbitMQ nodes as the suite's broker (GRIDFLEET_TEST_BROKER=rabbitmq): the
    interface of MosquittoBroker the tests use, and the cluster's own (`node_urls`, `kill_node`,
    `start_node`, `pause_node`, `resume_node`, `pids`).

    `url` is every node's TCP URL, comma-separated, and each read begins at the next node. The
    nodes cluster at their first boot (classic peer discovery: node 0 starts a cluster, the others
    join it). `kill_node` then `start_node` brings a node back on its data (its retained store
    among them: node-local in 3.10, rabbitmq-server #8096). `stop` then `start` is a new cluster
    that kept nothing, as Mosquitto without persistence: RabbitMQ 3.10.8's MQTT plugin cannot
    restart all nodes at once on their data (each waits for a leader of its client-id tracking,
    a Raft cluster, that needs its own vote: "client ID registration timed out", for minutes).
    With `definitions` (`gridfleet accounts rabbitmq`) the nodes load those accounts at their first
    boot and refuse anonymous clients; `login` is then the account the readiness check logs in as.
    """

    WS_PATH = "/ws"  # where the web MQTT plugin serves MQTT over websockets

    def __init__(
        self,
        directory: Path,
        nodes: int = 3,
        definitions: Path | None = None,
        login: tuple[str, str] | None = None,
    ) -> None:
        self.directory = directory
        self.definitions = definitions
        self.login = login
        self.epmd_port = free_port()
        self.dist_ports = [free_port() for _ in range(nodes)]
        super().__init__(nodes)
        tag = secrets.token_hex(3)
        self.names = [f"rabbit-{tag}-{i}@localhost" for i in range(nodes)]
        self._cookie = secrets.token_hex(20)
        self._epmd: subprocess.Popen[bytes] | None = None
        self._nodes: list[subprocess.Popen[bytes] | None] = [None] * nodes
        self._beams: list[int | None] = [None] * nodes
        self.started_in_s: float | None = None  # how long the last `start` took

    # The interface the tests use.

    @property
    def pids(self) -> list[int]:
        """The process ids of the nodes' Erlang VMs running (in order), then the epmd's."""
        running = [
            beam
            for beam, proc in zip(self._beams, self._nodes, strict=True)
            if beam is not None and proc is not None and proc.poll() is None
        ]
        if self._epmd is not None and self._epmd.poll() is None:
            running.append(self._epmd.pid)
        return running

    # Files and environment.

    def _node_dir(self, i: int) -> Path:
        return self.directory / f"node{i}"

    def log(self, i: int) -> Path:
        """Node `i`'s RabbitMQ log."""
        return self._node_dir(i) / "log" / f"{self.names[i]}.log"

    def _tail(self, i: int, lines: int = 30) -> str:
        for path in (self.log(i), self._node_dir(i) / "stdout.log"):
            if path.exists():
                return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
        return "(no log)"

    def env(self, i: int) -> dict[str, str]:
        """The environment node `i` runs in; rabbitmqctl run in it speaks to node `i`."""
        node = self._node_dir(i)
        home = self.directory / "home"
        return {
            **os.environ,
            # Erlang's cookie file is ~/.erlang.cookie, for the server and its CLI tools alike.
            "HOME": str(home),
            "ERL_EPMD_PORT": str(self.epmd_port),
            "ERL_EPMD_ADDRESS": "127.0.0.1",
            "ERL_CRASH_DUMP": str(node / "erl_crash.dump"),
            "RABBITMQ_NODENAME": self.names[i],
            "RABBITMQ_MNESIA_BASE": str(node / "mnesia"),
            "RABBITMQ_LOG_BASE": str(node / "log"),
            "RABBITMQ_CONFIG_FILE": str(node / "rabbitmq.conf"),
            "RABBITMQ_ADVANCED_CONFIG_FILE": str(node / "advanced.config"),
            "RABBITMQ_CONF_ENV_FILE": str(node / "rabbitmq-env.conf"),
            "RABBITMQ_ENABLED_PLUGINS_FILE": str(node / "enabled_plugins"),
            "RABBITMQ_PID_FILE": str(node / "rabbit.pid"),
            "RABBITMQ_DIST_PORT": str(self.dist_ports[i]),
            # Distribution (other nodes, CLI tools) on loopback only; never an epmd of its own
            # (one started as a daemon when the cluster's died would outlive the cluster).
            "RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS": (
                "-kernel inet_dist_use_interface {127,0,0,1} -start_epmd false"
            ),
            "RABBITMQ_CTL_ERL_ARGS": "-start_epmd false",
        }

    def _write_node_files(self, i: int) -> None:
        node = self._node_dir(i)
        node.mkdir(parents=True, exist_ok=True)
        home = self.directory / "home"
        home.mkdir(exist_ok=True)
        cookie = home / ".erlang.cookie"
        if not cookie.exists():
            cookie.write_text(self._cookie)
            cookie.chmod(0o400)  # Erlang refuses a cookie others may read
        peers = [] if i == 0 else [self.names[0], self.names[i]]
        (node / "rabbitmq.conf").write_text(
            rabbitmq_conf(
                port=self.ports[i],
                ws_port=self.ws_ports[i],
                definitions=self.definitions,
                peers=peers,
            )
            + "log.console = false\nlog.file.level = info\n"
        )
        (node / "enabled_plugins").write_text(PLUGINS)

    def ctl(self, i: int, *args: str, timeout: float = 60.0) -> str:
        """rabbitmqctl `args` against node `i` (on this cluster's epmd, a CLI port of its own)."""
        cli_port = str(free_port())
        env = {
            **self.env(i),
            "RABBITMQ_CTL_DIST_PORT_MIN": cli_port,
            "RABBITMQ_CTL_DIST_PORT_MAX": cli_port,
        }
        done = subprocess.run(
            [str(SBIN / "rabbitmqctl"), "-n", self.names[i], *args],
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout,
            stdin=subprocess.DEVNULL,
        )
        if done.returncode != 0:
            raise ClusterError(f"rabbitmqctl {' '.join(args)}: {done.stdout}{done.stderr}")
        return done.stdout

    # Processes.

    def _start_epmd(self) -> None:
        if self._epmd is not None and self._epmd.poll() is None:
            return
        with (self.directory / "epmd.log").open("ab") as out:
            self._epmd = subprocess.Popen(
                [EPMD, "-port", str(self.epmd_port), "-address", "127.0.0.1"],
                stdout=out,
                stderr=out,
                stdin=subprocess.DEVNULL,
            )

        def up() -> bool:
            if self._epmd is None or self._epmd.poll() is not None:
                raise ClusterError("epmd exited")
            with socket.socket() as probe:
                return probe.connect_ex(("127.0.0.1", self.epmd_port)) == 0

        wait_until(up, 10, what="epmd listening")

    def _spawn(self, i: int) -> None:
        if not (SBIN / "rabbitmq-server").exists():
            raise ClusterError(
                "rabbitmq-server 3.10.8 is not installed: apt-get install rabbitmq-server"
            )
        proc = self._nodes[i]
        assert proc is None or proc.poll() is not None, f"node {i} runs"
        self._write_node_files(i)
        node = self._node_dir(i)
        with (node / "stdout.log").open("ab") as out:
            self._nodes[i] = subprocess.Popen(
                [str(SBIN / "rabbitmq-server")],
                env=self.env(i),
                cwd=node,
                stdout=out,
                stderr=out,
                stdin=subprocess.DEVNULL,
                start_new_session=True,  # a process group of its own, killed as one
            )
        self._beams[i] = None

    def _ready(self, i: int) -> bool:
        """Whether node `i` takes an MQTT client (its client-id tracking is up); fails when its
        process ended."""
        proc = self._nodes[i]
        assert proc is not None, f"node {i} was never started"
        if proc.poll() is not None:
            raise ClusterError(f"node {i} exited ({proc.returncode}):\n{self._tail(i)}")
        if self._beams[i] is None:
            self._beams[i] = _beam_of(proc)
        code = _mqtt_connack(self.ports[i], f"gridfleet-ready-{i}", self.login)
        return code == 0

    def _await(self, which: list[int], timeout: float) -> None:
        pending = set(which)

        def all_ready() -> bool:
            for i in sorted(pending):
                if self._ready(i):
                    pending.discard(i)
            return not pending

        wait_until(
            all_ready,
            timeout,
            interval=0.2,
            what=f"rabbitmq nodes {sorted(pending)} taking MQTT clients",
            context=lambda: "\n".join(f"node {i}:\n{self._tail(i, 8)}" for i in sorted(pending)),
        )

    def start_node(self, i: int, timeout: float = START_TIMEOUT_S) -> None:
        """Start node `i` (again) on its own ports and data; it rejoins the cluster."""
        self._start_epmd()
        self._spawn(i)
        try:
            self._await([i], timeout)
        except BaseException:
            self._kill(i)
            raise

    def _wrapper(self, i: int) -> subprocess.Popen[bytes]:
        proc = self._nodes[i]
        assert proc is not None and proc.poll() is None, f"node {i} is not running"
        return proc

    def _beam(self, i: int) -> int:
        self._wrapper(i)
        if self._beams[i] is None:
            self._beams[i] = _beam_of(self._wrapper(i))
        beam = self._beams[i]
        assert beam is not None, f"node {i} has no Erlang VM"
        return beam

    def kill_node(self, i: int) -> None:
        """SIGKILL node `i`'s Erlang VM: its clients' links drop, nothing is flushed."""
        self._kill(i)

    def _kill(self, i: int) -> None:
        """SIGKILL node `i`'s process group (the script, the VM, its helpers) and reap it."""
        proc = self._nodes[i]
        if proc is None:
            return
        with suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)  # its own session: nothing else is in it
        proc.wait(10)
        beam = self._beams[i]
        if beam is not None:  # the script's child: reaped by init once the script is gone
            wait_until(lambda: not _alive(beam), 10, what=f"node {i}'s VM gone")
        self._nodes[i] = None
        self._beams[i] = None

    def stop_node(self, i: int, timeout: float = 30.0) -> None:
        """Stop node `i` as its service would (SIGTERM: a clean shutdown, the others notified)."""
        proc = self._wrapper(i)
        beam = self._beam(i)
        os.kill(beam, signal.SIGCONT)
        proc.terminate()  # the script stops the VM and waits for it
        with suppress(subprocess.TimeoutExpired):
            proc.wait(timeout)
        self._kill(i)

    def pause_node(self, i: int) -> None:
        """SIGSTOP node `i`'s VM: its sockets stay open, nothing answers."""
        os.kill(self._beam(i), signal.SIGSTOP)

    def resume_node(self, i: int) -> None:
        """SIGCONT node `i`'s VM."""
        os.kill(self._beam(i), signal.SIGCONT)

    def _schema_ready(self, i: int) -> bool:
        """Whether node `i` is past its database boot step (its tables in their final form)."""
        proc = self._nodes[i]
        if proc is None or proc.poll() is not None:
            raise ClusterError(f"node {i} exited:\n{self._tail(i)}")
        log = self.log(i)
        return log.exists() and "Running boot step database_sync" in log.read_text(errors="replace")

    def start(self, timeout: float = START_TIMEOUT_S) -> None:
        """Start a new cluster (no data kept from a `stop`) and wait until each node takes MQTT
        clients: node 0 begins it; the others start once its tables are made (one that joins
        while node 0 still migrates its tables to the feature flags' forms fails its schema check
        and stops) and join it one at a time. Two joining at once could leave one out of the
        MQTT plugin's client-id cluster (Raft) for good: "mqtt_node: leader call - leader not
        known" for 120 s, in a loaded CI run."""
        self.directory.mkdir(parents=True, exist_ok=True)
        began = time.monotonic()
        for i in range(len(self._nodes)):  # a cluster of its own again (see the class)
            shutil.rmtree(self._node_dir(i) / "mnesia", ignore_errors=True)
        try:
            self._start_epmd()
            self._spawn(0)
            wait_until(lambda: self._schema_ready(0), timeout, interval=0.1, what="node 0's tables")
            for i in range(1, len(self._nodes)):
                self._spawn(i)
                self._await([i], timeout)  # in the client-id cluster before the next one joins
            self._await(list(range(len(self._nodes))), timeout)
        except BaseException:
            self._teardown()
            raise
        self.started_in_s = time.monotonic() - began

    def stop(self, timeout: float = 30.0) -> None:
        """Stop every node at once (SIGTERM, a clean shutdown; SIGKILL past `timeout`); their data
        stays for `start`. Every client is disconnected."""
        running = [i for i, p in enumerate(self._nodes) if p is not None and p.poll() is None]
        for i in running:
            os.kill(self._beam(i), signal.SIGCONT)
            self._wrapper(i).terminate()
        deadline = time.monotonic() + timeout
        for i in running:
            proc = self._nodes[i]
            assert proc is not None
            with suppress(subprocess.TimeoutExpired):
                proc.wait(max(0.1, deadline - time.monotonic()))
        for i in range(len(self._nodes)):
            self._kill(i)

    def _teardown(self) -> None:
        """SIGKILL every node and the epmd: nothing of the cluster is left running."""
        for i in range(len(self._nodes)):
            self._kill(i)
        if self._epmd is not None:
            if self._epmd.poll() is None:
                self._epmd.kill()
            self._epmd.wait(10)
            self._epmd = None

    def restart(self) -> None:
        """Stop and start again on the same ports."""
        self.stop()
        self.start()

    def allow_origins(self, *origins: str, timeout: float = 10.0) -> None:
        """As BrokerThread's; nothing to do: RabbitMQ's web MQTT checks no origin (protocol.md
        section 10)."""

    def __enter__(self) -> RabbitCluster:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._teardown()
