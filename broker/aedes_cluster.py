"""An aedes cluster on one machine: a Redis and three aedes instances (broker/aedes/launcher.mjs)
sharing it, on free loopback ports, everything in a folder of its own (the test suite's broker
kind `aedes`, `gridfleet bench soak --cluster aedes`)."""

from __future__ import annotations

import shutil
import signal
import subprocess
from pathlib import Path

from gridfleet.broker.aedes import LAUNCHER, launcher_command
from gridfleet.broker.cluster_nodes import ClusterError, NodeList, end, listening, wait_until
from gridfleet.ports import free_port

REDIS = shutil.which("redis-server") or "/usr/bin/redis-server"
NODE = shutil.which("node") or "node"
# A survivor publishes the wills of a dead instance 3 to 7 heartbeats after its last one (aedes
# checks every 4 heartbeats for instances silent for 3): 60 s by default, 1 s here (3-7 s).
HEARTBEAT_MS = 1000


class AedesCluster(NodeList):
    """aedes instances on one Redis as the suite's broker (GRIDFLEET_TEST_BROKER=aedes): the
    interface of MosquittoBroker the tests use, and the cluster's own (`node_urls`, `kill_node`,
    `start_node`, `pause_node`, `resume_node`, `pids`).

    `url` is every instance's TCP URL, comma-separated, and each read of it begins at the next
    instance: consecutive clients start on different instances, each able to fail over. Redis
    keeps nothing on disk: `stop` then `start` is a cluster that kept nothing, as Mosquitto without
    persistence; `kill_node` then `start_node` is an instance back on Redis's state.
    """

    def __init__(
        self,
        directory: Path,
        nodes: int = 3,
        accounts_file: Path | None = None,
        heartbeat_ms: int = HEARTBEAT_MS,
    ) -> None:
        self.directory = directory
        self.accounts_file = accounts_file
        self.heartbeat_ms = heartbeat_ms
        self.redis_port = free_port()
        super().__init__(nodes)
        self._redis: subprocess.Popen[bytes] | None = None
        self._nodes: list[subprocess.Popen[bytes] | None] = [None] * nodes

    @property
    def redis_url(self) -> str:
        """The Redis every instance shares."""
        return f"redis://127.0.0.1:{self.redis_port}"

    @property
    def pids(self) -> list[int]:
        """The process ids of the instances running (in order), then Redis's."""
        running = [p.pid for p in self._nodes if p is not None and p.poll() is None]
        if self._redis is not None and self._redis.poll() is None:
            running.append(self._redis.pid)
        return running

    def _log(self, name: str) -> Path:
        return self.directory / f"{name}.log"

    def _start_redis(self, timeout: float) -> None:
        if not Path(REDIS).exists():
            raise ClusterError("redis-server is not installed: apt-get install redis-server")
        folder = self.directory / "redis"
        folder.mkdir(parents=True, exist_ok=True)
        with self._log("redis").open("ab") as out:
            self._redis = proc = subprocess.Popen(
                [
                    REDIS,
                    "--port",
                    str(self.redis_port),
                    "--bind",
                    "127.0.0.1",
                    "--save",
                    "",
                    "--appendonly",
                    "no",
                    "--dir",
                    str(folder),
                ],
                stdout=out,
                stderr=out,
            )

        def up() -> bool:
            if proc.poll() is not None:
                raise ClusterError(f"redis-server exited: {self._log('redis').read_text()}")
            return listening(self.redis_port)

        wait_until(up, timeout, what="redis-server listening")

    def start_node(self, i: int, timeout: float = 20.0) -> None:
        """Start instance `i` (again) on its own ports, and wait until both listen."""
        if not (LAUNCHER.parent / "node_modules" / "aedes").is_dir():
            raise ClusterError(
                f"{LAUNCHER.parent}/node_modules is missing: run npm ci there (make install does)"
            )
        assert self._nodes[i] is None or self._nodes[i].poll() is not None, f"node {i} runs"  # type: ignore[union-attr]
        command = launcher_command(
            self.accounts_file,
            redis_url=self.redis_url,
            port=self.ports[i],
            ws_port=self.ws_ports[i],
            instance_id=f"aedes-{i}",
            heartbeat_ms=self.heartbeat_ms,
            node=NODE,
        )
        log = self._log(f"aedes-{i}")
        with log.open("ab") as out:
            self._nodes[i] = proc = subprocess.Popen(command, stdout=out, stderr=out)

        def up() -> bool:
            if proc.poll() is not None:
                raise ClusterError(f"aedes-{i} exited: {log.read_text()}")
            return listening(self.ports[i]) and listening(self.ws_ports[i])

        try:
            wait_until(up, timeout, what=f"aedes-{i} listening")
        except BaseException:
            end(proc)
            raise

    def _node(self, i: int) -> subprocess.Popen[bytes]:
        proc = self._nodes[i]
        assert proc is not None and proc.poll() is None, f"aedes-{i} is not running"
        return proc

    def kill_node(self, i: int) -> None:
        """SIGKILL instance `i`: its clients' links drop, its wills wait for a survivor."""
        proc = self._node(i)
        proc.kill()
        proc.wait(10)

    def stop_node(self, i: int) -> None:
        """Stop instance `i` as its service would (SIGTERM): it sends its clients' wills."""
        end(self._node(i))

    def pause_node(self, i: int) -> None:
        """SIGSTOP instance `i`: its sockets stay open, nothing answers."""
        self._node(i).send_signal(signal.SIGSTOP)

    def resume_node(self, i: int) -> None:
        """SIGCONT instance `i`."""
        self._node(i).send_signal(signal.SIGCONT)

    def start(self, timeout: float = 30.0) -> None:
        """Start Redis, then every instance, and wait until they listen."""
        self.directory.mkdir(parents=True, exist_ok=True)
        try:
            self._start_redis(timeout)
            for i in range(len(self._nodes)):
                self.start_node(i, timeout)
        except BaseException:
            self.stop()
            raise

    def stop(self, timeout: float = 5.0) -> None:
        """Stop every instance, then Redis (every client is disconnected, nothing is kept)."""
        # All at once: one by one, a client of the first would fail over to the next, to be cut
        # off again (a single broker's restart cuts each client once).
        running = [p for p in self._nodes if p is not None and p.poll() is None]
        for proc in running:
            proc.send_signal(signal.SIGCONT)
            proc.terminate()
        for proc in running:
            end(proc, timeout)
        self._nodes = [None] * len(self._nodes)
        if self._redis is not None:
            end(self._redis, timeout)
            self._redis = None

    def restart(self) -> None:
        """Stop and start again on the same ports."""
        self.stop()
        self.start()

    def allow_origins(self, *origins: str, timeout: float = 10.0) -> None:
        """As BrokerThread's; nothing to do: the launcher checks no origin (protocol.md section
        10)."""

    def __enter__(self) -> AedesCluster:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
