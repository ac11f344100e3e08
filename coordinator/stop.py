"""The emergency stop as the coordinator keeps it (protocol.md §5.1), without I/O.

One owner for everything about the stop: the latch and the presses seen (`StopView`), whether
the fleet is stopped, what must go back on the broker after a reconnect, and which of a step's
orders the stop withdraws. Each call returns what to publish; the core adds what the whole fleet
does about it (a halt order for every unit, its status, the event).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gridfleet.outbound import Outbound
from gridfleet.protocol import EstopSignal, Topics, decode_estop, encode_estop
from gridfleet.protocol.stop import LATCH, StopView

# After connecting, how long the retained latch may take to arrive before the broker is taken to
# have lost it (as units wait for it: protocol.md §5.1).
LATCH_WAIT_S = 1.0


@dataclass(frozen=True)
class StopNews:
    """What one stop payload changed: messages to publish, and in words when the fleet changed."""

    publish: list[Outbound] = field(default_factory=list)
    line: str | None = None  # None: the fleet was stopped (or running) before and still is
    # A retained latch not taken (a failover's stale `released`), in words; nothing was applied.
    stale: str | None = None


class FleetStop:
    """The fleet's stop: `engaged` when the latch or a held press stops it."""

    def __init__(self, topics: Topics) -> None:
        self.topics = topics
        self.view = StopView()
        self.engaged = False
        # After a (re)connect: when the retained latch can have arrived; None once it did, or
        # once we re-asserted it (a restarted broker without persistence lost it).
        self._latch_due: float | None = None
        # Likewise for the presses we hold: those the broker did not replay by then it lost.
        self._presses_due: float | None = None
        self._replayed: set[str] = set()  # press topics replayed since the last (re)connect
        # The session is on another broker than the one before (a failover): its retained latch
        # may be one that broker kept while the fleet was stopped elsewhere (node-local retained
        # messages: RabbitMQ's), so one saying other than the stop we hold is not taken.
        self._moved = False
        self._releasing: set[Outbound] = set()  # the last step's orders that release squares

    def connected(self, now: float, moved: bool = False) -> None:
        """(Re)connected: the retained latch and presses are due within LATCH_WAIT_S.

        `moved`: on another broker than the session before (a failover, not a reconnect to the
        same one): a retained latch that would release the stop held is re-asserted, not taken.
        """
        self._latch_due = now + LATCH_WAIT_S
        self._moved = moved
        self._presses_due = now + LATCH_WAIT_S
        self._replayed = set()

    def latch_out(self, signal: EstopSignal) -> Outbound:
        """`signal` on the latch, retained (restored, re-asserted or copied from a press)."""
        return Outbound.of(LATCH, self.topics.fleet(LATCH), encode_estop(signal))

    def on_payload(
        self, kind: str, source: str | None, topic: str, payload: bytes, retained: bool = False
    ) -> StopNews:
        """The latch or a press; a bad payload raises ProtocolError before changing anything.

        `retained`: the broker replayed it on subscribing (it was not published since).
        """
        if kind == LATCH and retained:
            stale = self._stale(payload)
            if stale is not None:
                return stale
        was_latched = self.view.latch_engaged
        signal = self.view.apply(kind, source, topic, payload)
        if kind != LATCH:
            self._replayed.add(topic)
        if kind == LATCH:
            self._latch_due = None  # the broker still has the latch: nothing to re-assert
        publish: list[Outbound] = []
        if kind == LATCH and signal is not None and not signal.engaged and was_latched:
            # An operator's release: the presses are cleared, or a restart would read them again.
            # Only a latch going from engaged to released is one: the retained `released` a
            # reconnect replays is no release of a press that came after it (the safe side).
            for held in self.view.release_presses():
                publish.append(Outbound.of(self.topics.parse(held)[0], held, b""))
        elif kind != LATCH and signal is not None and not self.view.latch_engaged:
            # Mirrored into the latch, which only operators release: a source that clears or
            # overwrites its own press cannot release the fleet.
            publish.append(self.latch_out(signal))
        if self.view.engaged == self.engaged:
            return StopNews(publish)  # engaging (or releasing) is idempotent
        self.engaged = self.view.engaged
        cause = self.view.cause or signal
        if cause is not None:
            word = "ENGAGED" if self.engaged else "released"
            line = f"emergency stop {word} by {cause.by}: {cause.reason}"
        else:
            # The last press cleared (by us, before a restart) while the latch said released:
            # its copy on the latch may still be on its way and would engage again.
            line = f"emergency stop released: {source}'s press was cleared"
        return StopNews(publish, line)

    def _stale(self, payload: bytes) -> StopNews | None:
        """The retained latch of a broker failed over to, when it would release the stop held.

        That broker may never have seen the stop (a cluster whose retained messages are
        node-local, or brokers that share nothing): its `released` (or `released` with no press
        it knows) is no operator's release. The stop held goes out on the latch again, retained,
        and an operator releases it there. Only the first latch of the session counts (the
        broker replays it before anything published since), and only while it is due: a
        broker that marks live messages retained cannot keep a release from ever being taken.
        """
        cause = self.view.cause
        if not self._moved or self._latch_due is None or not self.engaged or cause is None:
            return None
        signal = decode_estop(payload)  # a bad one raises: healed, as on any connection
        if signal.engaged:
            return None  # agrees: the fleet stays stopped, by whoever it names
        self._latch_due = None  # answered: what it has is replaced now
        line = (
            f"emergency stop held: the retained latch on the broker failed over to says released "
            f"by {signal.by}, which is no release; re-asserted ({cause.by})"
        )
        return StopNews([self.latch_out(cause)], stale=line)

    def heal(self, topic: str) -> list[Outbound]:
        """The retained engaged stop again, when a payload that is no signal replaced it.

        A malformed or empty payload on `estop` is ignored by every receiver, but on the broker
        it replaces (an empty one deletes) the retained `engaged`: after a restart the stop would
        be gone. The last valid engaged signal goes out again, unchanged (protocol.md §5.1).
        """
        latch = self.view.latch
        if topic != self.topics.fleet(LATCH) or latch is None or not latch.engaged:
            return []
        return [self.latch_out(latch)]

    def reassert(self, now: float) -> tuple[list[Outbound], str | None]:
        """The engaged latch again, when no retained latch came after connecting; and why.

        A broker restarted without persistence has lost every retained message, the latch among
        them: a unit connecting now would find no stop (protocol.md §5.1). A latch an operator
        released while we were away does arrive, and is then not overridden.
        """
        if self._presses_due is not None and now >= self._presses_due:
            self._presses_due = None
            lost = [topic for topic in self.view.presses if topic not in self._replayed]
            if lost and not self.view.latch_engaged:
                # A press we hold the broker no longer has (and the latch does not say engaged):
                # latched below, since only latched can an operator release it (a release is
                # the latch going from engaged to released).
                self._latch_due = now
        if self._latch_due is None or now < self._latch_due:
            return [], None
        self._latch_due = None
        cause = self.view.cause
        if cause is None:
            return [], None
        # The engaged latch, or a held press (engaged too).
        return [self.latch_out(cause)], f"emergency stop re-asserted on the broker ({cause.by})"

    def releasing(self, orders: set[Outbound]) -> None:
        """The orders of the step just made that release squares (the stop may withdraw them)."""
        self._releasing = orders

    def withdrawn(self, out: Outbound) -> bool:
        """Whether `out`, of the last step, must not go out after all: an order that releases
        squares, once the stop was engaged while the step's messages were going out (the halt
        orders already went, and the stop wins at once)."""
        return self.engaged and out in self._releasing
