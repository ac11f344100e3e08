"""The answers given to requests, by sender and request id: a retry gets the first answer again.

Clients re-send a request (same `request_id`) until its reply arrives, because a loaded broker
can drop either (protocol.md §6). A retry must change nothing: the coordinator answers it from
here. Pure; the shell stores each new Answer beside the jobs, so a retry after a restart is still
recognised. Bounded: the latest ANSWERS_KEPT answers are kept (a submit with a client-chosen job
id is recognised for good by the job itself, requests.py).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from gridfleet.coordinator.requests import Outcome
from gridfleet.protocol.messages import Request

ANSWERS_KEPT = 10_000  # several minutes of requests at the rates a busy fleet sees


def digest(req: Request) -> str:
    """A fingerprint of what `req` asks: its type and every field but the header."""
    content = type(req).__name__ + req.model_dump_json(exclude={"header"})
    return hashlib.blake2b(content.encode("utf-8"), digest_size=12).hexdigest()


@dataclass(frozen=True)
class Answer:
    """The answer given to one request, and what that request asked."""

    sender: str
    request_id: str
    digest: str
    outcome: Outcome

    def to_dict(self) -> dict[str, Any]:
        """Plain data for storage."""
        o = self.outcome
        return {
            "sender": self.sender,
            "request_id": self.request_id,
            "digest": self.digest,
            "accepted": o.accepted,
            "reason": o.reason,
            "job_id": o.job_id,
            "code": o.code,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Answer:
        """Inverse of to_dict."""
        outcome = Outcome(bool(d["accepted"]), d["reason"], d["job_id"], d.get("code"))
        return cls(str(d["sender"]), str(d["request_id"]), str(d["digest"]), outcome)


class Answers:
    """The latest answers, oldest first; `recall` before deciding, `remember` after."""

    def __init__(self, kept: int = ANSWERS_KEPT) -> None:
        self.kept = kept
        self._by_key: OrderedDict[tuple[str, str], Answer] = OrderedDict()

    def __len__(self) -> int:
        return len(self._by_key)

    def restore(self, answers: Iterable[Answer]) -> None:
        """Answers given before a restart, oldest first."""
        for answer in answers:
            self._keep(answer)

    def recall(self, req: Request) -> Outcome | None:
        """What to answer `req` without deciding anew; None when it is a new request.

        The first answer when it is a retry (same sender, id and content). A refusal when its
        sender used the id for a different request: answering that with the other request's
        answer would tell it something false, and carrying it out would make the id ambiguous.
        """
        known = self._by_key.get((req.header.sender, req.request_id))
        if known is None:
            return None
        if known.digest == digest(req):
            return known.outcome
        return Outcome(
            False,
            f"request id {req.request_id!r} was already used by {req.header.sender} for a "
            "different request: give every request its own id",
            code="conflict",
        )

    def remember(self, req: Request, outcome: Outcome) -> Answer:
        """Keep the answer given to the new request `req`; returns it, for the store."""
        answer = Answer(req.header.sender, req.request_id, digest(req), outcome)
        self._keep(answer)
        return answer

    def _keep(self, answer: Answer) -> None:
        key = (answer.sender, answer.request_id)
        self._by_key.pop(key, None)
        self._by_key[key] = answer
        while len(self._by_key) > self.kept:
            self._by_key.popitem(last=False)
