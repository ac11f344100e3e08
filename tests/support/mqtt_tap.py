"""A TCP relay between one MQTT client and its broker that records the client's packets: what a
device really sends (its CONNECT and will, its SUBSCRIBEs with their QoS, each PUBLISH)."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from dataclasses import dataclass, field
from types import TracebackType


@dataclass(frozen=True)
class Packet:
    """One MQTT packet the client sent, decoded as far as the tests need."""

    connection: int  # 1 for the client's first connection through the tap, then 2, ...
    kind: int  # the MQTT packet type: 1 CONNECT, 3 PUBLISH, 4 PUBACK, 8 SUBSCRIBE, ...
    flags: int
    body: bytes
    at: float = field(default=0.0, compare=False)  # time.monotonic() when it passed

    def _string(self, at: int) -> tuple[str, int]:
        n = int.from_bytes(self.body[at : at + 2], "big")
        return self.body[at + 2 : at + 2 + n].decode(), at + 2 + n

    def connect_fields(self) -> dict[str, object]:
        """A CONNECT's client id, clean session flag and will (topic, payload, QoS, retain)."""
        assert self.kind == 1
        _, at = self._string(0)  # protocol name
        flags = self.body[at + 1]
        client_id, at = self._string(at + 4)  # level, flags, keep-alive
        out: dict[str, object] = {"client_id": client_id, "clean": bool(flags & 0x02)}
        if flags & 0x04:
            out["will_topic"], at = self._string(at)
            payload, at = self._string(at)
            out.update(
                will_payload=payload, will_qos=(flags >> 3) & 3, will_retain=bool(flags & 0x20)
            )
        return out

    def subscriptions(self) -> list[tuple[str, int]]:
        """A SUBSCRIBE's topic filters with their requested QoS."""
        assert self.kind == 8
        out, at = [], 2  # after the packet id
        while at < len(self.body):
            topic, at = self._string(at)
            out.append((topic, self.body[at]))
            at += 1
        return out

    def publish_fields(self) -> tuple[str, bytes, int, bool]:
        """A PUBLISH's topic, payload, QoS and retain flag."""
        assert self.kind == 3
        qos = (self.flags >> 1) & 3
        topic, at = self._string(0)
        return topic, self.body[at + (2 if qos else 0) :], qos, bool(self.flags & 1)


def _read_exact(sock: socket.socket, n: int, buffer: bytearray) -> bytes | None:
    while len(buffer) < n:
        chunk = sock.recv(65536)
        if not chunk:
            return None
        buffer.extend(chunk)
    out = bytes(buffer[:n])
    del buffer[:n]
    return out


class MqttTap:
    """Listens on a free loopback port and relays each connection to the broker on
    `broker_port`; a connection the broker does not take is closed at once (as a broker that is
    down would leave the client without an answer)."""

    def __init__(self, broker_port: int) -> None:
        self.broker_port = broker_port
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port: int = self._server.getsockname()[1]
        self._lock = threading.Lock()
        self._packets: list[Packet] = []
        self._connections = 0
        self._open: list[socket.socket] = []
        self._closed = False
        threading.Thread(target=self._accept, name="mqtt-tap", daemon=True).start()

    def packets(self, kind: int | None = None) -> list[Packet]:
        """The client's packets so far, of `kind` if given."""
        with self._lock:
            return [p for p in self._packets if kind is None or p.kind == kind]

    def _accept(self) -> None:
        while not self._closed:
            try:
                client, _ = self._server.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection(("127.0.0.1", self.broker_port), timeout=2)
            except OSError:
                client.close()
                continue
            upstream.settimeout(None)
            with self._lock:
                self._connections += 1
                number = self._connections
                self._open += [client, upstream]
            threading.Thread(target=self._up, args=(client, upstream, number), daemon=True).start()
            threading.Thread(target=self._down, args=(upstream, client), daemon=True).start()

    def _up(self, client: socket.socket, upstream: socket.socket, number: int) -> None:
        """Client to broker, packet by packet, recording each."""
        buffer = bytearray()
        try:
            while True:
                head = _read_exact(client, 1, buffer)
                if head is None:
                    break
                length, shift, raw = 0, 0, bytearray(head)
                while True:
                    digit = _read_exact(client, 1, buffer)
                    if digit is None:
                        raise OSError("closed inside a header")
                    raw += digit
                    length |= (digit[0] & 0x7F) << shift
                    shift += 7
                    if not digit[0] & 0x80:
                        break
                body = _read_exact(client, length, buffer) if length else b""
                if body is None:
                    break
                packet = Packet(number, head[0] >> 4, head[0] & 0x0F, body, time.monotonic())
                with self._lock:
                    self._packets.append(packet)
                upstream.sendall(bytes(raw) + body)
        except OSError:
            pass
        finally:
            self._close(client, upstream)

    def _down(self, upstream: socket.socket, client: socket.socket) -> None:
        """Broker to client, as it comes."""
        try:
            while chunk := upstream.recv(65536):
                client.sendall(chunk)
        except OSError:
            pass
        finally:
            self._close(client, upstream)

    def _close(self, *socks: socket.socket) -> None:
        for sock in socks:
            with contextlib.suppress(OSError):  # the other pump may have closed it already
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()

    def close(self) -> None:
        """Stop listening and close every relayed connection."""
        self._closed = True
        self._server.close()
        with self._lock:
            socks, self._open = self._open, []
        self._close(*socks)

    def __enter__(self) -> MqttTap:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
