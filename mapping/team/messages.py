"""What agents send each other, and its real serialised form (bytes are counted as ``len(to_bytes())``).

Two kinds, as the paper's exchange (sec. III-D), a third for the transmission baseline and a fourth
for DSGD:
- ``ParameterMessage``: per instance, its network vector, box, frame and code-book entry, and, the
  first time that instance goes to that peer (or after its cloud grew), its down-sampled point cloud
  for the Cross-Agent Instance Alignment.
- ``RayMessage``: camera poses of views the sender has mapped (by default drawn from the frames it read
  before this round; ``ConsistencyConfig.ray_poses``) and a sampling seed the receiver
  replays to get the same pixels (never depth: the receiver renders the peer's depth itself with the
  peer's parameters, eq. 13).
- ``PointCloudMessage``: the down-sampled points the sender has observed so far: what point-cloud
  sharing (the paper's Table VI baseline) would send instead of parameters; it trains nothing here,
  it exists so that its bytes are counted the same way as the others'.
- ``DegreeMessage``: DSGD only, after the parameters arrived: the sender's pairs with the receiver
  and its degree per instance, so that both ends of an edge use the same Metropolis weight
  (``mapping.team.consistency``).

Wire format (one function pair for both kinds): ``b"OMMSG"``, a version byte, a uint32 header length,
a UTF-8 JSON header (scalars, and for each array its name, dtype, shape and offset), then the arrays'
raw little-endian bytes. Parameters may travel as float16 (``encode_params``).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field

import numpy as np

MAGIC = b"OMMSG"
VERSION = 1
_DTYPES = {"float16", "float32", "float64", "int32", "int64", "uint8"}


class MessageError(ValueError):
    """Bytes that are not a message of this version (truncated, corrupt, or of another kind)."""


@dataclass
class InstancePayload:
    """One instance as it travels.

    Attributes:
        instance_id: the sender's id for it.
        bank: ``object`` or ``structure`` (network width).
        params: (D,) float16 or float32 network vector.
        bound_lo, bound_hi: (3,) float32 box.
        frame_centre: (3,) float32; ``frame_half``, ``frame_origin``, ``frame_version``: its frame.
        caption, caption_feature ((d,) float16/32), confidence: its code-book entry.
        cloud: (P, 3) float32 down-sampled points, or None (already sent).
    """

    instance_id: int
    bank: str
    params: np.ndarray
    bound_lo: np.ndarray
    bound_hi: np.ndarray
    frame_centre: np.ndarray
    frame_half: float
    frame_origin: int
    frame_version: int
    caption: str
    caption_feature: np.ndarray
    confidence: float
    cloud: np.ndarray | None = None


@dataclass
class ParameterMessage:
    """Sender's instances for one receiver in one round; ``degree`` = how many peers the sender sent
    parameters to this round (informational: DSGD's weights come from ``DegreeMessage``)."""

    sender: int
    receiver: int
    round: int
    instances: list[InstancePayload] = field(default_factory=list)
    degree: int = 1
    kind = "params"


@dataclass
class RayMessage:
    """Camera poses of views the sender has mapped ((F, 4, 4) float32, camera-to-world), its intrinsics
    (fx, fy, cx, cy, width, height), and the seed and count of the pixels to replay per pose."""

    sender: int
    receiver: int
    round: int
    poses: np.ndarray
    intrinsics: tuple[float, float, float, float, int, int]
    seed: int
    rays_per_pose: int
    kind = "rays"


@dataclass
class PointCloudMessage:
    """The sender's observed points so far, (P, 3) float32, down-sampled (point-cloud sharing)."""

    sender: int
    receiver: int
    round: int
    points: np.ndarray
    kind = "points"


@dataclass
class DegreeMessage:
    """DSGD's listing for one receiver: per pair of the sender's instance ``own_ids[m]`` with the
    receiver's ``peer_ids[m]``, the sender's degree for that instance ``degrees[m]`` ((n,) int each)."""

    sender: int
    receiver: int
    round: int
    own_ids: np.ndarray
    peer_ids: np.ndarray
    degrees: np.ndarray
    kind = "degrees"


Message = ParameterMessage | RayMessage | PointCloudMessage | DegreeMessage


def replay_pixels(message: RayMessage) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pixels a ray message stands for: (M,) pose index, (M,) u and (M,) v, M = poses x count.

    Sender and receiver both call this: the seed fixes the pixels, so only the seed travels."""
    width, height = int(message.intrinsics[4]), int(message.intrinsics[5])
    rng = np.random.default_rng(message.seed)
    n = len(message.poses) * message.rays_per_pose
    pose = np.repeat(np.arange(len(message.poses)), message.rays_per_pose)
    return pose, rng.integers(0, width, n), rng.integers(0, height, n)


# ---- wire format -------------------------------------------------------------------------------------
def _pack(kind: str, scalars: dict, arrays: dict[str, np.ndarray]) -> bytes:
    table, blobs, offset = [], [], 0
    for name, array in arrays.items():
        a = np.ascontiguousarray(array)
        if a.dtype.name not in _DTYPES:
            raise TypeError(f"array {name}: dtype {a.dtype} cannot travel")
        blob = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
        table.append([name, a.dtype.name, list(a.shape), offset])
        blobs.append(blob)
        offset += len(blob)
    header = json.dumps({"kind": kind, "scalars": scalars, "arrays": table}, separators=(",", ":")).encode()
    return MAGIC + bytes([VERSION]) + struct.pack("<I", len(header)) + header + b"".join(blobs)


def _unpack(data: bytes) -> tuple[str, dict, dict[str, np.ndarray]]:
    """Header and arrays of ``data``; every table entry is checked before it is read, because a message
    that crossed a process or a machine may be anything."""
    if len(data) < len(MAGIC) + 5 or not data.startswith(MAGIC):
        raise MessageError("not an OpenMulti message (bad magic)")
    if data[len(MAGIC)] != VERSION:
        raise MessageError(f"message version {data[len(MAGIC)]}, this code reads {VERSION}")
    start = len(MAGIC) + 1
    (n,) = struct.unpack("<I", data[start:start + 4])
    if start + 4 + n > len(data):
        raise MessageError(f"truncated message (header of {n} bytes)")
    try:
        header = json.loads(data[start + 4:start + 4 + n].decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MessageError(f"corrupt message header ({exc})") from None
    if not (isinstance(header, dict) and isinstance(header.get("kind"), str)
            and isinstance(header.get("scalars"), dict) and isinstance(header.get("arrays"), list)):
        raise MessageError("corrupt message header (expected kind, scalars and arrays)")
    body = memoryview(data)[start + 4 + n:]
    arrays = {}
    for entry in header["arrays"]:
        if not (isinstance(entry, list) and len(entry) == 4 and isinstance(entry[0], str)):
            raise MessageError(f"corrupt array entry {entry!r} (expected [name, dtype, shape, offset])")
        name, dtype, shape, offset = entry
        if dtype not in _DTYPES:
            raise MessageError(f"array {name}: dtype {dtype!r} cannot travel (one of {sorted(_DTYPES)})")
        if not (isinstance(shape, list) and all(_count(d) for d in shape)):
            raise MessageError(f"array {name}: shape {shape!r} is not a list of non-negative integers")
        if not _count(offset):
            raise MessageError(f"array {name}: offset {offset!r} is not a non-negative integer")
        dt = np.dtype(dtype).newbyteorder("<")
        size = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        if offset + size > len(body):
            raise MessageError(f"truncated message (array {name})")
        arrays[name] = np.frombuffer(body[offset:offset + size], dtype=dt).reshape(shape).astype(dtype)
    return header["kind"], header["scalars"], arrays


def _count(value) -> bool:
    """A JSON non-negative integer (bool is not one)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _checked(arrays: dict[str, np.ndarray], name: str, shape: tuple[int | None, ...], floating: bool = True
             ) -> np.ndarray:
    """``arrays[name]`` if it has ``shape`` (None: any length) and, for floats, only finite values."""
    if name not in arrays:
        raise MessageError(f"array {name} is missing")
    a = arrays[name]
    if a.ndim != len(shape) or any(want is not None and got != want for got, want in zip(a.shape, shape)):
        want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + ")"
        raise MessageError(f"array {name}: shape {a.shape}, expected {want}")
    if floating and (a.dtype.kind != "f" or not np.all(np.isfinite(a))):
        raise MessageError(f"array {name}: expected finite floats, got {a.dtype} "
                           f"{'with non-finite values' if a.dtype.kind == 'f' else ''}".rstrip())
    return a


def _checked_ids(arrays: dict[str, np.ndarray], name: str) -> np.ndarray:
    """``arrays[name]`` if it is a (n,) array of non-negative integers."""
    a = _checked(arrays, name, (None,), floating=False)
    if a.dtype.kind not in "iu" or np.any(a < 0):
        raise MessageError(f"array {name}: expected non-negative integers, got {a.dtype}")
    return a.astype(np.int64)


def to_bytes(message: Message) -> bytes:
    """The message's serialised form (what a radio would carry)."""
    base = {"sender": message.sender, "receiver": message.receiver, "round": message.round}
    if isinstance(message, PointCloudMessage):
        return _pack("points", base, {"points": np.asarray(message.points, np.float32)})
    if isinstance(message, DegreeMessage):
        return _pack("degrees", base, {name: np.asarray(getattr(message, name), np.int32)
                                       for name in ("own_ids", "peer_ids", "degrees")})
    if isinstance(message, RayMessage):
        return _pack("rays", {**base, "intrinsics": list(message.intrinsics), "seed": int(message.seed),
                              "rays_per_pose": int(message.rays_per_pose)},
                     {"poses": np.asarray(message.poses, np.float32)})
    scalars = {**base, "degree": message.degree, "instances": []}
    arrays = {}
    for k, inst in enumerate(message.instances):
        scalars["instances"].append({"id": inst.instance_id, "bank": inst.bank, "half": float(inst.frame_half),
                                     "origin": inst.frame_origin, "version": inst.frame_version,
                                     "caption": inst.caption, "confidence": float(inst.confidence),
                                     "cloud": inst.cloud is not None})
        arrays[f"{k}.params"] = inst.params
        arrays[f"{k}.box"] = np.concatenate([inst.bound_lo, inst.bound_hi, inst.frame_centre]).astype(np.float32)
        arrays[f"{k}.feature"] = inst.caption_feature
        if inst.cloud is not None:
            arrays[f"{k}.cloud"] = np.asarray(inst.cloud, np.float32)
    return _pack("params", scalars, arrays)


def from_bytes(data: bytes) -> Message:
    """Inverse of ``to_bytes``; anything else (truncated, corrupt, an array of the wrong shape or dtype,
    non-finite values) raises MessageError naming the field, so nothing malformed is ever applied."""
    kind, s, a = _unpack(bytes(data))
    try:
        base = (_int(s, "sender"), _int(s, "receiver"), _int(s, "round"))
        if kind == "rays":
            fx, fy, cx, cy, w, h = s["intrinsics"]
            return RayMessage(*base, _checked(a, "poses", (None, 4, 4)), (fx, fy, cx, cy, int(w), int(h)),
                              _int(s, "seed"), _int(s, "rays_per_pose"))
        if kind == "points":
            return PointCloudMessage(*base, _checked(a, "points", (None, 3)))
        if kind == "degrees":
            lists = [_checked_ids(a, name) for name in ("own_ids", "peer_ids", "degrees")]
            if len({len(x) for x in lists}) != 1:
                raise MessageError(f"arrays own_ids, peer_ids, degrees: lengths {[len(x) for x in lists]} differ")
            if np.any(lists[2] < 1):
                raise MessageError("array degrees: every degree must be >= 1")
            return DegreeMessage(*base, *lists)
        if kind != "params":
            raise MessageError(f"unknown message kind {kind!r}")
        instances = []
        for k, meta in enumerate(s["instances"]):
            box = _checked(a, f"{k}.box", (9,))
            cloud = _checked(a, f"{k}.cloud", (None, 3)) if meta["cloud"] else None
            instances.append(InstancePayload(meta["id"], meta["bank"], _checked(a, f"{k}.params", (None,)),
                                             box[:3], box[3:6], box[6:9], meta["half"], meta["origin"],
                                             meta["version"], meta["caption"], _checked(a, f"{k}.feature", (None,)),
                                             meta["confidence"], cloud))
        return ParameterMessage(*base, instances, _int(s, "degree"))
    except (KeyError, ValueError, TypeError) as exc:
        if isinstance(exc, MessageError):
            raise
        raise MessageError(f"corrupt message body ({type(exc).__name__}: {exc})") from None


def _int(scalars: dict, name: str) -> int:
    """``scalars[name]`` if it is a non-negative integer."""
    if not _count(scalars.get(name)):
        raise MessageError(f"field {name}: {scalars.get(name)!r} is not a non-negative integer")
    return scalars[name]
