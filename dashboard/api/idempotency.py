"""`Idempotency-Key`: a submit sent again is the same job, never a second one (pure).

The key makes the job's id and the request's id, `k-` + blake2b(account NUL key, 10 bytes) in
hex: the coordinator answers a request id it has answered with that answer again (kept across
its restarts), and recognises a job id taken by the same sender with the same body as that job
for good (protocol.md §6, §6.1). So a retry after a timeout, a 503 or a restart of the
coordinator or of the dashboard gets the one job; nothing is stored here. The same key with
another body is refused by the coordinator (the id is taken): `idempotency_key_reused`.
"""

from __future__ import annotations

import hashlib

PREFIX = "k-"
DIGEST_BYTES = 10


def derived_id(account: str, key: str) -> str:
    """The job id (and request id) of `account`'s submit with Idempotency-Key `key`."""
    digest = hashlib.blake2b(f"{account}\0{key}".encode(), digest_size=DIGEST_BYTES)
    return PREFIX + digest.hexdigest()


def reused_words(key: str, job_id: str) -> str:
    """Why a submit with a key already used for another body is refused."""
    shown = key if len(key) <= 40 else key[:37] + "..."
    return (
        f"Idempotency-Key {shown!r} was used before for another job ({job_id}): a retry sends "
        "the same body with its key, a new job a new key"
    )
