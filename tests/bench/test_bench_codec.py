"""`gridfleet bench codec`: each way of reading and writing the hot path's messages is timed, and
msgspec's validated Structs read what the protocol writes and refuse what it refuses."""

from __future__ import annotations

import json

import msgspec
import pytest

from gridfleet.bench.codec import samples
from gridfleet.bench.codec_structs import STRUCTS
from gridfleet.protocol import encode

from support.cli import gridfleet


def test_the_bench_times_every_way_for_every_message_and_says_it_in_json() -> None:
    done = gridfleet("bench", "codec", "--repeat", "2", "--number", "20", "--json")
    assert done.returncode == 0, done.stderr
    figures = json.loads(done.stdout)
    assert set(figures) == {"state", "order", "jobs view"}
    for message, ways in figures.items():
        assert "pydantic (today)" in ways and "msgspec, no validation" in ways
        assert ("msgspec Structs, validated" in ways) == (message != "jobs view")
        for f in ways.values():
            assert f["write_us"] > 0 and f["read_us"] > 0 and f["bytes"] > 100


@pytest.mark.parametrize("flags", [["--repeat", "0"], ["--number", "0"]])
def test_bad_flags_are_one_line(flags: list[str]) -> None:
    done = gridfleet("bench", "codec", *flags)
    assert done.returncode == 2
    assert done.stderr.strip().count("\n") == 0 and "at least 1" in done.stderr


@pytest.mark.parametrize("name", ["UnitState", "Order"])
def test_the_structs_read_what_the_protocol_writes_and_refuse_a_square_off_the_grid(
    name: str,
) -> None:
    message = next(m for m in samples().values() if type(m).__name__ == name)
    decoder = msgspec.json.Decoder(STRUCTS[name])
    payload = encode(message)
    assert json.loads(msgspec.json.encode(decoder.decode(payload))) == json.loads(payload)
    bad = json.loads(payload)
    bad["released"] = [[5000, 1]]
    with pytest.raises(msgspec.ValidationError):
        decoder.decode(json.dumps(bad))
