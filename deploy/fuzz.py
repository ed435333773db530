"""Hostile payloads for a key: random bytes, random MessagePack, and a live message with one field made hostile.

Pure: a seeded ``random.Random`` and a template (a message seen live on the key, or none)
give the payloads; ``contactflow bench fuzz`` sends them to a deployment.
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from typing import Any

import msgpack

HOSTILE: tuple[Any, ...] = (
    float("nan"), float("inf"), -float("inf"), 1e308, -1.0, 0, -1, 2**63 - 1, -(2**63), 2**64 - 1,
    "", "x" * 10_000, "../../*", "\x00", None, True, [], {}, [float("nan")] * 3, b"\xff" * 64,
)
"""Values a field is replaced with: non-finite and extreme numbers, edge integers, wrong types, odd strings."""


def random_value(rng: random.Random, depth: int = 0) -> Any:
    """A random MessagePack value, nested at most three levels, often hostile."""
    kind = rng.randrange(7 if depth < 3 else 4)
    if kind == 0:
        return rng.choice(HOSTILE[:10])
    if kind == 1:
        return rng.uniform(-1e6, 1e6)
    if kind == 2:
        return "".join(chr(rng.randrange(32, 127)) for _ in range(rng.randrange(12)))
    if kind == 3:
        return rng.choice((None, True, False, rng.randrange(-1000, 1000)))
    if kind == 4:
        return [random_value(rng, depth + 1) for _ in range(rng.randrange(5))]
    if kind == 5:
        return {"type": rng.choice(("event", "status", "clock", "robot_state", "arm_command", "control", "x")),
                **{f"f{i}": random_value(rng, depth + 1) for i in range(rng.randrange(5))}}
    return b"".join(bytes([rng.randrange(256)]) for _ in range(rng.randrange(16)))


def _paths(value: Any, prefix: tuple = ()) -> Iterator[tuple]:
    """Every path to a leaf or container of a decoded message (map keys and list indices)."""
    yield prefix
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(value, list):
        for i, v in enumerate(value[:8]):
            yield from _paths(v, (*prefix, i))


def mutate(template: bytes, rng: random.Random) -> bytes:
    """The template with the value at one random path replaced by a hostile one (or the template cut short)."""
    try:
        msg = msgpack.unpackb(template, raw=False, strict_map_key=False)
    except Exception:  # noqa: BLE001 - a template that is not MessagePack is cut instead
        msg = None
    paths = [p for p in _paths(msg) if p] if isinstance(msg, dict) else []
    if not paths or rng.random() < 0.15:
        return template[: rng.randrange(max(1, len(template)))]
    path = rng.choice(paths)
    node = msg
    for step in path[:-1]:
        node = node[step]
    node[path[-1]] = rng.choice(HOSTILE)
    return msgpack.packb(msg, use_bin_type=True)


def payloads(rng: random.Random, template: bytes | None, n: int) -> Iterator[tuple[str, bytes]]:
    """``n`` payloads as (kind, bytes): random bytes, random MessagePack, mutated template (when there is one)."""
    kinds = ("bytes", "msgpack", "mutated") if template else ("bytes", "msgpack")
    for i in range(n):
        kind = kinds[i % len(kinds)]
        if kind == "bytes":
            yield kind, bytes(rng.randrange(256) for _ in range(rng.randrange(2048)))
        elif kind == "msgpack":
            yield kind, msgpack.packb(random_value(rng), use_bin_type=True)
        else:
            assert template is not None
            yield kind, mutate(template, rng)
