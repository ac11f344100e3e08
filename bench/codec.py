"""`gridfleet bench codec`: what reading and writing the hot path's messages costs, and how much
a faster JSON library could save (issue 57).

Today's codec is pydantic's (`gridfleet.protocol.encode`/`decode`: JSON parsed and validated in
one pass, strictly). It is timed side by side, alternating, against the bounds a faster library
could reach: orjson and msgspec parsing and writing the same bytes without validating anything
(a lower bound: the protocol's checks at the edge would have to come back on top), and orjson
parsing followed by pydantic's validation of the Python objects. Each figure is the median of
`--repeat` rounds of `--number` calls, in microseconds a message.

The messages are a moving unit's state (each unit, every step), an order (to each unit that
drives) and a jobs view of 100 jobs (sent whole on each change).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from datetime import UTC, datetime
from typing import Any

from gridfleet.errors import ConfigError
from gridfleet.protocol import PROTOCOL_VERSION, JobsView, UnitState, decode, encode
from gridfleet.protocol import Order as OrderMessage
from gridfleet.protocol.messages import Message

Timed = Callable[[], object]


def _header(sender: str) -> dict[str, Any]:
    return {
        "version": PROTOCOL_VERSION,
        "seq": 41_234,
        "timestamp": datetime(2026, 12, 4, 18, 0, tzinfo=UTC).isoformat(),
        "sender": sender,
    }


def samples() -> dict[str, Message]:
    """The three messages, as a busy fleet sends them."""
    square = [12, 7]
    state = UnitState.model_validate(
        {
            "header": _header("unit17"),
            "step": 41_234,
            "position": square,
            "direction": "E",
            "status": "moving",
            "job_id": "job-2803",
            "load_kg": 1.5,
            "leds": {"E": True},
            "sensors": {"N": "wall", "E": "free", "S": "unit", "W": "free"},
            "order_id": "unit17-job-2803",
            "order_update_id": 88,
            "released": [[13, 7], [14, 7], [15, 7]],
            "battery_pct": 71.5,
        }
    )
    order = OrderMessage.model_validate(
        {
            "header": _header("coordinator"),
            "order_id": "unit17-job-2803",
            "update_id": 89,
            "step": 41_235,
            "released": [[13, 7], [14, 7], [15, 7]],
            "planned": [[15, 7 + n] for n in range(1, 21)],
            "target": [15, 27],
            "action": {"kind": "drop", "job_id": "job-2803", "square": [15, 27], "mass_kg": 1.5},
        }
    )
    jobs = JobsView.model_validate(
        {
            "header": _header("coordinator"),
            "jobs": [
                {
                    "id": f"job-{2800 + n}",
                    "pickup": [n % 30, 3],
                    "dropoff": [29 - n % 30, 25],
                    "mass_kg": 1.0,
                    "state": "to_pickup" if n % 3 else "queued",
                    **({"unit": f"unit{n % 30 + 1}"} if n % 3 else {}),
                }
                for n in range(100)
            ],
            "counts": {"done": 2700, "queued": 34, "to_pickup": 66},
        }
    )
    return {"state": state, "order": order, "jobs view": jobs}


def candidates(message: Message) -> dict[str, tuple[Timed, Timed]]:
    """name -> (write, read) of `message`, each a call with no arguments."""
    import msgspec
    import orjson

    model = type(message)
    payload = encode(message)
    as_python = json.loads(payload)
    ways: dict[str, tuple[Timed, Timed]] = {
        "pydantic (today)": (lambda: encode(message), lambda: decode(model, payload)),
        "orjson, then pydantic validates": (
            lambda: orjson.dumps(message.model_dump(mode="json")),
            lambda: model.model_validate(orjson.loads(payload)),
        ),
        "orjson, no validation": (lambda: orjson.dumps(as_python), lambda: orjson.loads(payload)),
        "msgspec, no validation": (
            lambda: msgspec.json.encode(as_python),
            lambda: msgspec.json.decode(payload),
        ),
    }
    from gridfleet.bench.codec_structs import STRUCTS

    struct = STRUCTS.get(model.__name__)
    if struct is not None:
        decoder = msgspec.json.Decoder(struct)
        typed = decoder.decode(payload)  # it must read what pydantic wrote
        ways["msgspec Structs, validated"] = (
            lambda: msgspec.json.encode(typed),
            lambda: decoder.decode(payload),
        )
    return ways


def _per_call_us(call: Timed, number: int) -> float:
    started = time.perf_counter()
    for _ in range(number):
        call()
    return (time.perf_counter() - started) / number * 1e6


def measure(repeat: int, number: int) -> dict[str, dict[str, dict[str, float]]]:
    """message -> candidate -> {"write_us", "read_us"}: medians of rounds taken in turn."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for name, message in samples().items():
        ways = candidates(message)
        writes: dict[str, list[float]] = {way: [] for way in ways}
        reads: dict[str, list[float]] = {way: [] for way in ways}
        order = list(ways)
        for n in range(repeat):
            for way in order[n % len(order) :] + order[: n % len(order)]:  # each first in turn
                write, read = ways[way]
                writes[way].append(_per_call_us(write, number))
                reads[way].append(_per_call_us(read, number))
        size = len(encode(message))
        out[name] = {
            way: {
                "write_us": round(statistics.median(writes[way]), 2),
                "read_us": round(statistics.median(reads[way]), 2),
                "bytes": size,
            }
            for way in ways
        }
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of `gridfleet bench codec`."""
    parser.add_argument("--repeat", type=int, default=9, help="rounds, alternating (default 9)")
    parser.add_argument("--number", type=int, default=2000, help="calls a round (default 2000)")
    parser.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    """Entry point of `gridfleet bench codec`."""
    if args.repeat < 1 or args.number < 1:
        raise ConfigError("--repeat and --number: give at least 1")
    try:
        figures = measure(args.repeat, args.number)
    except ModuleNotFoundError as exc:
        raise ConfigError(f"bench codec needs {exc.name}: pip install 'gridfleet[bench]'") from None
    if args.json:
        print(json.dumps(figures, indent=2))
        return 0
    for message, ways in figures.items():
        today = ways["pydantic (today)"]
        print(f"{message} ({today['bytes']:.0f} bytes), microseconds a message, median:")
        for way, f in ways.items():
            ratio = (f["write_us"] + f["read_us"]) / (today["write_us"] + today["read_us"])
            print(
                f"  {way:<34} write {f['write_us']:8.2f}  read {f['read_us']:8.2f}  "
                f"({ratio:.2f} x today)"
            )
    return 0
