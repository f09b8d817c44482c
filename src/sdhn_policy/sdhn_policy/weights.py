"""Actor weights: one safetensors blob with metadata, as bytes (ROS message) or files (disk).

NumPy + safetensors only, so actor processes can load weights without torch. Nothing here ever
unpickles. Every loader validates format, sha256, tensor names, shapes, dtypes and finiteness
*before* returning, and raises :class:`WeightsError` with the reason otherwise.

Bytes form (the fields of the ROS ``sdhn_msgs/PolicyWeights`` message)::

    blob = encode_actor(spec, tensors, version=3)   # ActorWeights(format, version, payload, sha256)
    spec, tensors = decode_actor(blob.format, blob.version, blob.payload, blob.sha256)

File form: ``<stem>.safetensors`` (the payload) plus ``<stem>.json`` (format, version, sha256,
spec), both written atomically (temp file, fsync, rename)::

    save_actor_file("actor.safetensors", blob); blob = load_actor_file("actor.safetensors")
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import struct
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from safetensors.numpy import load as st_load
from safetensors.numpy import save as st_save

from sdhn_base import bounded_json
from sdhn_base.drops import DropKind
from sdhn_base.litter import clean_stale_tmp
from sdhn_policy.features import check_transform, feature_size

ACTOR_FORMAT = "sdhn-actor/2"
"""Format string of the actor blob; bump the number on any incompatible change.
``sdhn-actor/2`` adds the spec's ``features`` (the input transform of the raw observation)."""
RETIRED_FORMATS = {
    "sdhn-actor/1": "it predates input features (it was trained on absolute coordinates); "
                    "retrain, or export again with this version",
}

MAX_SPEC_SIZE = 1 << 24
"""Largest size a spec may name (observation length, widths, robots): a float32 tensor with
more columns than this cannot fit in any payload an actor accepts."""
MAX_HIDDEN_LAYERS = 64

Tensors = dict[str, npt.NDArray[np.float32]]


class WeightsError(ValueError):
    """A weights payload or file was rejected; ``reason`` says why, ``kind`` names the class of
    fault (an actor counts and logs rejections once per kind)."""

    kind = DropKind.BAD_WEIGHTS

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class UnknownFormatError(WeightsError):
    """The message names a weights format this runtime does not read."""

    kind = DropKind.UNKNOWN_FORMAT


class Sha256MismatchError(WeightsError):
    """The payload does not hash to the sha256 the message carries."""

    kind = DropKind.BAD_SHA256


class BadTensorsError(WeightsError):
    """The payload is no valid safetensors blob, or its tensors do not match the spec."""

    kind = DropKind.BAD_TENSORS


class OversizedPayloadError(WeightsError):
    """The payload is larger than an actor accepts."""

    kind = DropKind.OVERSIZED_PAYLOAD


class IncompatibleWeightsError(WeightsError):
    """Valid weights that this actor cannot use (e.g. trained for another team size)."""

    kind = DropKind.INCOMPATIBLE_WEIGHTS


@dataclass(frozen=True)
class ActorSpec:
    """Shape of the shared actor network (everything needed to rebuild it)."""

    obs_size: int  # D: length of one robot's raw local observation (what the env sends)
    num_actions: int  # A: size of the categorical policy
    hidden_sizes: tuple[int, ...] = (64,)  # MLP encoder widths (ReLU after each layer)
    gru_hidden: int = 64  # GRU hidden size; 0 = no GRU (feed-forward: the head reads the MLP)
    use_robot_id: bool = False  # append a one-hot robot id of length num_robots to the obs
    num_robots: int = 0  # N (only used for the one-hot id)
    features: str = "identity"  # sdhn_policy.features transform applied to the raw observation

    @property
    def feature_size(self) -> int:
        return feature_size(self.features, self.obs_size)

    @property
    def input_size(self) -> int:
        return self.feature_size + (self.num_robots if self.use_robot_id else 0)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["hidden_sizes"] = list(self.hidden_sizes)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ActorSpec:
        try:
            spec = cls(
                obs_size=int(d["obs_size"]),
                num_actions=int(d["num_actions"]),
                hidden_sizes=tuple(int(x) for x in d["hidden_sizes"]),
                gru_hidden=int(d["gru_hidden"]),
                use_robot_id=bool(d["use_robot_id"]),
                num_robots=int(d["num_robots"]),
                features=str(d["features"]),
            )
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise WeightsError(f"actor spec metadata is malformed: {_short(repr(e))}") from e
        spec.check()
        return spec

    def check(self) -> None:
        sizes = (self.obs_size, self.num_actions, self.gru_hidden, self.num_robots,
                 *self.hidden_sizes)
        if len(self.hidden_sizes) > MAX_HIDDEN_LAYERS or any(s > MAX_SPEC_SIZE for s in sizes):
            raise WeightsError(f"actor spec is too large (at most {MAX_HIDDEN_LAYERS} hidden "
                               f"layers, sizes up to {MAX_SPEC_SIZE}): {_short(str(self))}")
        if self.obs_size < 1 or self.num_actions < 1 or self.gru_hidden < 0:
            raise WeightsError(f"actor spec has a non-positive size (gru_hidden: negative): {self}")
        if any(h < 1 for h in self.hidden_sizes):
            raise WeightsError(f"actor spec has a non-positive hidden width: {self}")
        if self.use_robot_id and self.num_robots < 1:
            raise WeightsError("actor spec uses a robot id but num_robots < 1")
        try:
            check_transform(self.features, self.obs_size)
        except ValueError as e:
            raise WeightsError(f"actor spec: {e}") from e

    def tensor_shapes(self) -> dict[str, tuple[int, ...]]:
        """The exact tensor names and shapes of an actor with this spec."""
        shapes: dict[str, tuple[int, ...]] = {}
        width = self.input_size
        for k, h in enumerate(self.hidden_sizes):
            shapes[f"encoder.{k}.weight"] = (h, width)
            shapes[f"encoder.{k}.bias"] = (h,)
            width = h
        g = self.gru_hidden
        if g > 0:
            shapes["gru.weight_ih"] = (3 * g, width)
            shapes["gru.weight_hh"] = (3 * g, g)
            shapes["gru.bias_ih"] = (3 * g,)
            shapes["gru.bias_hh"] = (3 * g,)
            width = g
        shapes["head.weight"] = (self.num_actions, width)
        shapes["head.bias"] = (self.num_actions,)
        return shapes


@dataclass(frozen=True)
class ActorWeights:
    """The bytes form, field for field the ROS ``PolicyWeights`` message."""

    format: str
    version: int
    payload: bytes
    sha256: str


def _short(text: str, limit: int = 300) -> str:
    """``text`` cut to ``limit`` characters: a crafted payload must not make a log line huge."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def sha256_hex(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def validate_tensors(spec: ActorSpec, tensors: dict[str, np.ndarray]) -> Tensors:
    """Check names, shapes, dtype and finiteness against ``spec``; return float32 arrays."""
    expected = spec.tensor_shapes()
    missing = sorted(set(expected) - set(tensors))
    extra = sorted(set(tensors) - set(expected))
    if missing or extra:
        raise BadTensorsError(_short(
            f"tensor names do not match the spec: missing {missing}, unexpected {extra}"))
    out: Tensors = {}
    for name, shape in expected.items():
        a = tensors[name]
        if tuple(a.shape) != shape:
            raise BadTensorsError(f"tensor {name!r} has shape {tuple(a.shape)}, expected {shape}")
        if a.dtype != np.float32:
            raise BadTensorsError(f"tensor {name!r} has dtype {a.dtype}, expected float32")
        if not np.all(np.isfinite(a)):
            raise BadTensorsError(f"tensor {name!r} contains NaN or inf")
        out[name] = a
    return out


def encode_actor(spec: ActorSpec, tensors: dict[str, np.ndarray], version: int) -> ActorWeights:
    """Serialise an actor (validated first) into the bytes form."""
    spec.check()
    arrays = validate_tensors(
        spec, {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in tensors.items()}
    )
    metadata = {
        "format": ACTOR_FORMAT,
        "version": str(int(version)),
        "spec": json.dumps(spec.to_json(), sort_keys=True),
    }
    payload = canonical_safetensors(st_save(arrays, metadata=metadata))
    return ActorWeights(ACTOR_FORMAT, int(version), payload, sha256_hex(payload))


def canonical_safetensors(payload: bytes) -> bytes:
    """The same safetensors blob with its JSON header in sorted key order.

    safetensors writes metadata from a hash map, in an order that changes from call to call, so
    identical weights would get different bytes and checksums. Data offsets in the header are
    relative to the data section, so rewriting the header alone keeps the blob valid.
    """
    (length,) = struct.unpack("<Q", payload[:8])
    header = json.loads(payload[8 : 8 + length])
    text = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)  # the format pads the header to 8-byte alignment
    return struct.pack("<Q", len(text)) + text + payload[8 + length :]


def _read_metadata(payload: bytes) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors payload, parsed without loading any tensor."""
    if len(payload) < 8:
        raise WeightsError("payload is too short to be a safetensors blob")
    n = int.from_bytes(payload[:8], "little")
    if n <= 0 or 8 + n > len(payload):
        raise WeightsError("payload header length is out of range")
    try:
        header = bounded_json.loads(payload[8 : 8 + n])
    except bounded_json.JsonInputError as e:
        raise WeightsError(f"payload header rejected: {_short(str(e))}") from e
    meta = header.get("__metadata__") if isinstance(header, dict) else None
    if not isinstance(meta, dict):
        raise WeightsError("payload has no metadata (is it an sdhn actor blob?)")
    return {str(k): str(v) for k, v in meta.items()}


def decode_actor(fmt: str, version: int, payload: bytes, sha256: str) -> tuple[ActorSpec, Tensors]:
    """Validate the bytes form and return (spec, tensors). Raises WeightsError on any mismatch,
    and on anything else that goes wrong while decoding: a payload is data from the network, so
    no exception it provokes may escape the caller's drop-and-count path (and take a node down).
    """
    try:
        return _decode_actor(fmt, version, payload, sha256)
    except WeightsError:
        raise
    except Exception as e:  # a case the checks above missed: still a rejected payload
        raise WeightsError(f"payload rejected ({type(e).__name__}): {_short(str(e))}") from e


def _decode_actor(fmt: str, version: int, payload: bytes, sha256: str
                  ) -> tuple[ActorSpec, Tensors]:
    if fmt in RETIRED_FORMATS:
        raise UnknownFormatError(f"weights format {fmt!r} is no longer accepted: "
                                 f"{RETIRED_FORMATS[fmt]} (this runtime reads {ACTOR_FORMAT!r})")
    if fmt != ACTOR_FORMAT:
        raise UnknownFormatError(
            f"unknown weights format {_short(repr(fmt), 80)}; this runtime reads "
            f"{ACTOR_FORMAT!r}")
    payload = bytes(payload)
    actual = sha256_hex(payload)
    if actual != sha256.lower():
        raise Sha256MismatchError(
            f"sha256 mismatch: message says {sha256}, payload hashes to {actual}")
    meta = _read_metadata(payload)
    if meta.get("format") != ACTOR_FORMAT:
        raise WeightsError(f"payload metadata format is {_short(repr(meta.get('format')), 80)}, "
                           f"not {ACTOR_FORMAT!r}")
    if meta.get("version") != str(int(version)):
        raise WeightsError(f"payload version {_short(str(meta.get('version')), 40)} != message "
                           f"version {version}")
    if "spec" not in meta:
        raise WeightsError("payload metadata has no spec")
    try:
        spec_json = bounded_json.loads(meta["spec"])
    except bounded_json.JsonInputError as e:
        raise WeightsError(f"payload metadata spec rejected: {_short(str(e))}") from e
    if not isinstance(spec_json, dict):
        raise WeightsError("payload metadata spec is not a JSON object")
    spec = ActorSpec.from_json(spec_json)
    try:
        tensors = st_load(payload)
    except Exception as e:  # safetensors raises its own error type for corrupt blobs
        raise BadTensorsError(f"payload is not a valid safetensors blob: {e}") from e
    return spec, validate_tensors(spec, tensors)


def decode_weights(blob: ActorWeights) -> tuple[ActorSpec, Tensors]:
    return decode_actor(blob.format, blob.version, blob.payload, blob.sha256)


# --- files -----------------------------------------------------------------------------------


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` via a temp file in the same directory, fsync, then rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # The writer's pid is in the name, so a later start can tell a killed writer's leftover
    # (sdhn_base.litter.clean_stale_tmp, run below after every write) from a live one's.
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp",
                               dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    clean_stale_tmp(path.parent)
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def sidecar_path(path: str | os.PathLike[str]) -> Path:
    return Path(path).with_suffix(".json")


def save_actor_file(path: str | os.PathLike[str], blob: ActorWeights) -> None:
    """Write ``<stem>.safetensors`` and its ``<stem>.json`` sidecar, each atomically.

    Two files cannot be renamed at once, so the sidecar goes first and also names the payload it
    replaces (``previous``): a process killed between the two renames leaves the new sidecar
    with the old payload, which :func:`load_actor_file` still accepts as the old version."""
    spec, _ = decode_weights(blob)  # never write something we could not read back
    side: dict[str, Any] = {
        "format": blob.format,
        "version": blob.version,
        "sha256": blob.sha256,
        "spec": spec.to_json(),
    }
    try:
        old = json.loads(sidecar_path(path).read_text())
        side["previous"] = {k: old[k] for k in ("format", "version", "sha256")}
    except (OSError, ValueError, KeyError, TypeError):
        pass  # no (readable) earlier file: nothing to fall back to
    atomic_write_bytes(sidecar_path(path), json.dumps(side, indent=2).encode() + b"\n")
    atomic_write_bytes(path, blob.payload)


def read_regular_file(path: str | os.PathLike[str], limit: int = 1 << 30) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``limit`` bytes; WeightsError
    otherwise. Checked before opening: opening a FIFO blocks until a writer comes (an actor's
    executor stopped answering its lifecycle services), and a device never ends."""
    p = Path(path)
    try:
        info = os.stat(p)
    except FileNotFoundError:
        raise WeightsError(f"missing weights file: {p}") from None
    except OSError as e:
        raise WeightsError(f"cannot read {p}: {e.strerror}") from None
    if stat.S_ISDIR(info.st_mode):
        raise WeightsError(f"{p} is a directory, not a weights file")
    if not stat.S_ISREG(info.st_mode):
        raise WeightsError(f"{p} is not a regular file (a FIFO, socket or device); allowed: a "
                           "regular file")
    if info.st_size > limit:
        raise WeightsError(f"{p} is {info.st_size} bytes; allowed: at most {limit}")
    try:
        return p.read_bytes()
    except OSError as e:
        raise WeightsError(f"cannot read {p}: {e.strerror}") from None


def load_actor_file(path: str | os.PathLike[str]) -> ActorWeights:
    """Read and validate a weights file written by :func:`save_actor_file`."""
    path = Path(path)
    side_bytes = read_regular_file(sidecar_path(path), 1 << 20)
    payload = read_regular_file(path)
    try:
        side = bounded_json.loads(side_bytes)
        if not isinstance(side, dict):
            raise TypeError(f"expected a JSON object, got {type(side).__name__}")
        entry = side
        previous = side.get("previous")
        if (
            isinstance(previous, dict)
            and previous.get("sha256") == sha256_hex(payload)
            and side.get("sha256") != previous.get("sha256")
        ):
            entry = previous  # interrupted between the sidecar and the payload: the old pair
        blob = ActorWeights(
            str(entry["format"]), int(entry["version"]), payload, str(entry["sha256"])
        )
    except (KeyError, TypeError, ValueError, OverflowError) as e:
        raise WeightsError(f"weights sidecar {sidecar_path(path)} is malformed: "
                           f"{_short(repr(e))}") from e
    decode_weights(blob)
    return blob
