"""Crafted weights payloads (bytes, no ROS): the attacks on the header parser and a seeded
mutator for the fuzz test. Every payload comes with a matching sha256, so it gets past the
checksum to the parser (a wrong checksum is the easy case, tested elsewhere)."""

from __future__ import annotations

import json
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sdhn_policy.weights import ActorWeights, sha256_hex

DEEP = 200_000
"""Nesting levels of the deep-nesting attack: ~400 kB of brackets, far below the size cap."""


def split(payload: bytes) -> tuple[dict, bytes]:
    """(header JSON, data section) of a safetensors payload."""
    (n,) = struct.unpack("<Q", payload[:8])
    return json.loads(payload[8 : 8 + n]), payload[8 + n :]


def join(header_text: bytes, data: bytes) -> bytes:
    """A safetensors payload from raw header bytes (padded to 8 bytes as the format wants)."""
    header_text += b" " * (-len(header_text) % 8)
    return struct.pack("<Q", len(header_text)) + header_text + data


def dumps(header: dict) -> bytes:
    # allow_nan: the attacks need NaN/Infinity literals written out, as a crafted file has them.
    return json.dumps(header, allow_nan=True).encode()


def with_spec(good: ActorWeights, spec_text: str) -> bytes:
    """``good``'s payload with the metadata's spec string replaced by ``spec_text``."""
    header, data = split(good.payload)
    header["__metadata__"]["spec"] = spec_text
    return join(dumps(header), data)


def deep_header(good: ActorWeights) -> bytes:
    """The whole header nested ``DEEP`` levels deep (json.loads: RecursionError)."""
    _, data = split(good.payload)
    return join(b"[" * DEEP + b"]" * DEEP, data)


def deep_spec(good: ActorWeights) -> bytes:
    """A valid header whose spec string is JSON nested ``DEEP`` levels deep."""
    return with_spec(good, "[" * DEEP + "]" * DEEP)


def spec_number(good: ActorWeights, field: str, literal: str) -> bytes:
    """The spec with ``field`` written as the JSON number ``literal`` (NaN, Infinity, 1e999...)."""
    header, _ = split(good.payload)
    spec = json.loads(header["__metadata__"]["spec"])
    spec[field] = "@@"
    return with_spec(good, json.dumps(spec).replace('"@@"', literal))


ATTACKS: dict[str, Callable[[ActorWeights], bytes]] = {
    "deep_header": deep_header,
    "deep_spec": deep_spec,
    "spec_infinity": lambda g: spec_number(g, "obs_size", "Infinity"),
    "spec_nan": lambda g: spec_number(g, "gru_hidden", "NaN"),
    "spec_overflow": lambda g: spec_number(g, "num_actions", "1e999"),
    "spec_huge_int": lambda g: spec_number(g, "obs_size", "9" * 5000),
    "spec_huge_size": lambda g: spec_number(g, "obs_size", str(10**15)),
    "spec_hidden_inf": lambda g: spec_number(g, "hidden_sizes", "[-Infinity]"),
}
"""Name -> a payload (from a valid one) that must be rejected, not crash the receiver."""


@dataclass(frozen=True)
class Case:
    kind: str  # which mutation made it
    payload: bytes
    sha256: str


ODD_VALUES: list[object] = [
    None, True, -1, 0, 2**63, 2**64 + 7, 1.5, "x", "F32", [], {}, [1, 2], [-1], [2**62, 2**62],
    [0, 2**62], [10**30], ["a"], {"a": 1},
]
ODD_LITERALS = ["NaN", "Infinity", "-Infinity", "1e999", "-1e999", "9" * 400,
                "[" * 5000 + "]" * 5000, '"' + "\\u0000" * 10 + '"']
DTYPES = ["F32", "F64", "F16", "BF16", "I8", "I32", "I64", "U8", "BOOL", "F8_E4M3", "XX", ""]


def mutations(good: ActorWeights, seed: int, count: int) -> Iterator[Case]:
    """``count`` seeded mutations of ``good``'s payload: byte flips, truncations, random bytes,
    and structured edits of the header JSON (dtypes, shapes, offsets, metadata and spec fields
    set to odd values or to NaN/Infinity/overflowing/deeply nested literals)."""
    rng = np.random.default_rng(seed)
    base = good.payload
    header, data = split(base)
    tensor_names = sorted(k for k in header if k != "__metadata__")
    spec = json.loads(header["__metadata__"]["spec"])

    def pick(seq: list) -> object:
        return seq[int(rng.integers(len(seq)))]

    for _ in range(count):
        r = int(rng.integers(9))
        if r == 0:  # flip bytes anywhere (header or data)
            b = bytearray(base)
            for _ in range(int(rng.integers(1, 9))):
                b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(8))
            payload, kind = bytes(b), "flip"
        elif r == 1:
            payload, kind = base[: int(rng.integers(len(base)))], "truncate"
        elif r == 2:
            payload = rng.integers(0, 256, int(rng.integers(0, 256)), dtype=np.uint8).tobytes()
            kind = "random"
        elif r == 3:  # header length field off
            n = pick([0, 1, 7, len(base), 2**63, 2**64 - 1, int(rng.integers(1, 4096))])
            payload, kind = struct.pack("<Q", int(n)) + base[8:], "length"
        elif r in (4, 5):  # one tensor entry edited
            h = json.loads(json.dumps(header))
            entry = h[pick(tensor_names)]
            field = pick(["dtype", "shape", "data_offsets", "extra"])
            if field == "dtype":
                entry["dtype"] = pick(DTYPES + ODD_VALUES)
            elif field == "shape":
                entry["shape"] = pick([*ODD_VALUES,
                                       [int(rng.integers(0, 64)), int(rng.integers(0, 64))]])
            elif field == "data_offsets":
                a, z = entry["data_offsets"]
                entry["data_offsets"] = pick([*ODD_VALUES, [z, a], [a, z + 4], [a + 4, z],
                                              [a, len(data) + 8]])
            else:
                entry[pick(["extra", "dtype", ""])] = pick(ODD_VALUES)
            payload, kind = join(dumps(h), data), f"tensor_{field}"
        elif r == 6:  # one spec field set to an odd value or literal
            s = dict(spec)
            s[pick(sorted(s))] = "@@"
            text = json.dumps(s).replace('"@@"', str(pick(ODD_LITERALS))
                                         if rng.random() < 0.5 else json.dumps(pick(ODD_VALUES)))
            h = json.loads(json.dumps(header))
            h["__metadata__"]["spec"] = text
            payload, kind = join(dumps(h), data), "spec_field"
        elif r == 7:  # metadata edited: a key dropped or replaced, a literal in the header
            h = json.loads(json.dumps(header))
            key = pick(["format", "version", "spec", "__metadata__"])
            if key == "__metadata__":
                h["__metadata__"] = "@@"
            else:
                h["__metadata__"][key] = "@@"
            literal = str(pick(ODD_LITERALS)) if rng.random() < 0.7 else json.dumps(
                pick(ODD_VALUES))
            payload, kind = join(dumps(h).replace(b'"@@"', literal.encode()), data), "metadata"
        else:  # a known attack
            name = str(pick(sorted(ATTACKS)))
            payload, kind = ATTACKS[name](good), name
        yield Case(kind, payload, sha256_hex(payload))


def write_crafted_file(path: Path, good: ActorWeights, attack: str) -> Path:
    """A weights file pair (``path`` + its .json sidecar) holding ``ATTACKS[attack]`` of
    ``good``, with a sidecar whose sha256 matches, as a hostile file handed to a tool would."""
    from sdhn_policy.weights import save_actor_file

    save_actor_file(path, good)
    payload = ATTACKS[attack](good)
    path.write_bytes(payload)
    side = json.loads(path.with_suffix(".json").read_text())
    side["sha256"] = sha256_hex(payload)
    path.with_suffix(".json").write_text(json.dumps(side))
    return path
