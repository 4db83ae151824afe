"""The codec of a parameter message's vectors: quantisation, deltas against the receiver's copy, sparsification
with the remainder carried, as compressed exchange of network weights does in federated and distributed
learning (8-bit weights cost little; Deep Gradient Compression sends the largest entries of an update and keeps
the rest for later).

One function codes a vector and returns what the receiver will hold (``encode_vector``), one decodes it
(``decode_vector``), both with the same float32 arithmetic: sender and receiver hold the same reconstruction
bit for bit, so the sender's view of a peer's copy (acks, ``change``, ``copy_age``) is exact and deltas never
drift. A delta is always taken against that reconstruction, so whatever a message leaves out (rounding, the
entries sparsification drops) is in the next delta: no change is lost, only delayed (error feedback, without a
buffer of its own).

On the wire a coded vector is at most three arrays (``NAME.q`` codes, ``NAME.scale`` per block, ``NAME.index``
or ``NAME.mask`` for the kept entries of a sparse delta) and a small mapping of scalars (``coded_meta``);
``read_coded`` checks every one of them against the receiving team's rules before any vector is allocated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mapping.model.observed import UNKNOWN, ObservedSpace
from mapping.team.wire import MessageError, is_count

BITS = (4, 8, 16, 32)
CLOUD_BITS = (8, 16, 32)
"""Bits a cloud coordinate may take: 8 and 16 are integers over the cloud's own box, 32 is float32."""
"""Bits a coded value may take: 4 and 8 are integers with a float32 scale per block; 16 and 32 are float16 and
float32 (no scale)."""
META_FIELDS = frozenset({"n", "bits", "block", "base", "kept", "index"})
"""The scalars of one coded vector (``coded_meta``)."""
OPEN_VALUES_PER_BYTE, OPEN_VALUES_SLACK = 32, 1024
"""Where the receiver leaves a vector's length open (``MessageRules.param_counts`` None), a coded part may name at
most 32 values per byte it carries, plus 1024: a sparse delta of positions names at most 32 values a byte of
them, a mask 8; without this bound 600 bytes announced 2^24 values (64 MB decoded)."""
INDEX_FORMS = ("all", "index", "mask")
"""How the kept entries are named: every entry, their positions (int32, 4 bytes an entry) or a bit mask (one
bit an entry of the vector): the smaller of the two for a sparse delta."""


@dataclass(frozen=True)
class CodedVector:
    """A vector as it travels.

    Attributes:
        length: the vector's length (D).
        bits: bits of each sent value (``BITS``).
        block: values that share one scale (4 and 8 bits).
        codes: the sent values: packed unsigned integers (uint8) for 4 and 8 bits, float16 or float32 values.
        scales: (ceil(kept / block),) float32, one per block of sent values (empty for 16 and 32 bits).
        index: (kept,) int32 increasing positions of the sent values, or None (every entry, in order).
        base: the round of the copy this is a difference to (None: the vector itself).
    """

    length: int
    bits: int
    block: int
    codes: np.ndarray
    scales: np.ndarray
    index: np.ndarray | None
    base: int | None

    @property
    def kept(self) -> int:
        """How many values travel."""
        return self.length if self.index is None else len(self.index)


def quantise(values: np.ndarray, bits: int, block: int) -> tuple[np.ndarray, np.ndarray]:
    """``values`` as codes and per-block scales: symmetric, the block's largest magnitude at the largest code
    (round to nearest; what rounding loses a delta sends later)."""
    values = np.asarray(values, np.float32)
    if bits == 32:
        return values.copy(), np.zeros(0, np.float32)
    if bits == 16:
        return values.astype(np.float16), np.zeros(0, np.float32)
    top = (1 << (bits - 1)) - 1
    blocks = -(-len(values) // block)
    padded = np.zeros(blocks * block, np.float32)
    padded[:len(values)] = values
    grouped = padded.reshape(blocks, block)
    scales = (np.abs(grouped).max(axis=1) / np.float32(top)).astype(np.float32)
    safe = np.where(scales > 0, scales, np.float32(1))
    q = np.clip(np.rint(grouped / safe[:, None]), -top, top).astype(np.int16) + top
    return pack_unsigned(q.reshape(-1)[:len(values)].astype(np.uint8), bits), scales


def dequantise(codes: np.ndarray, scales: np.ndarray, bits: int, block: int, count: int) -> np.ndarray:
    """The float32 values ``quantise`` coded (the same arithmetic at both ends of a link)."""
    if bits in (16, 32):
        return np.asarray(codes, np.float32).reshape(-1)[:count].copy()
    top = (1 << (bits - 1)) - 1
    q = unpack_unsigned(codes, bits, count).astype(np.float32) - np.float32(top)
    with np.errstate(over="ignore", invalid="ignore"):  # a crafted scale may overflow: read_coded refuses it
        return (q * np.repeat(scales, block)[:count]).astype(np.float32)


def pack_unsigned(q: np.ndarray, bits: int) -> np.ndarray:
    """uint8 codes of ``bits`` bits packed into bytes (4 bits: two a byte, the first in the low half)."""
    if bits == 8:
        return q.astype(np.uint8)
    padded = np.zeros(-(-len(q) // 2) * 2, np.uint8)
    padded[:len(q)] = q
    return (padded[0::2] | (padded[1::2] << 4)).astype(np.uint8)


def unpack_unsigned(packed: np.ndarray, bits: int, count: int) -> np.ndarray:
    """Inverse of ``pack_unsigned``: the first ``count`` codes."""
    if bits == 8:
        return np.asarray(packed, np.uint8)[:count]
    out = np.empty(len(packed) * 2, np.uint8)
    out[0::2] = packed & 0x0F
    out[1::2] = packed >> 4
    return out[:count]


def code_bytes(count: int, bits: int) -> int:
    """Bytes of ``count`` codes of ``bits`` bits on the wire."""
    return -(-count * bits // 8)


def encode_vector(values: np.ndarray, bits: int, block: int, base: np.ndarray | None = None,
                  base_round: int | None = None, keep: float = 1.0) -> tuple[CodedVector, np.ndarray]:
    """``values`` coded, and the float32 vector the receiver will hold once it arrives.

    With ``base`` (the receiver's copy, acknowledged at ``base_round``) the difference travels, and with
    ``keep`` < 1 only its largest ``ceil(keep * D)`` entries: the receiver's copy moves by
    what travelled, and the next delta, taken against that copy, carries the rest."""
    values = np.asarray(values, np.float32).reshape(-1)
    if base is None:
        target, index = values, None
    else:
        base = np.asarray(base, np.float32).reshape(-1)
        if base.shape != values.shape:
            raise ValueError(f"a delta needs a base of the vector's length {len(values)}, got {len(base)}")
        target = (values - base).astype(np.float32)
        index = None
        if not target.any():  # nothing moved: a delta of no entries (a run of zeros compresses past any bound)
            index, target = np.zeros(0, np.int32), np.zeros(0, np.float32)
        elif keep < 1.0:
            k = max(1, math.ceil(keep * len(target)))
            if k < len(target):  # the k largest magnitudes (selection, not a sort: linear in D)
                index = np.sort(np.argpartition(-np.abs(target), k - 1)[:k]).astype(np.int32)
                target = target[index]
    codes, scales = quantise(target, bits, block)
    coded = CodedVector(len(values), bits, block, codes, scales, index, None if base is None else int(base_round))
    return coded, reconstruct(coded, base)


def decode_vector(coded: CodedVector) -> np.ndarray:
    """The (D,) float32 values a coded vector carries: the vector, or the difference to its base (zero where a
    sparse delta sent nothing)."""
    sent = dequantise(coded.codes, coded.scales, coded.bits, coded.block, coded.kept)
    if coded.index is None:
        return sent
    out = np.zeros(coded.length, np.float32)
    out[coded.index] = sent
    return out


def reconstruct(coded: CodedVector, base: np.ndarray | None) -> np.ndarray:
    """What the receiver holds once ``coded`` arrived: the decoded vector, or ``base`` plus the decoded delta."""
    values = decode_vector(coded)
    if coded.base is None:
        return values
    if base is None:
        raise ValueError("a delta arrived without the copy it is a difference to")
    return (np.asarray(base, np.float32).reshape(-1) + values).astype(np.float32)


def vector_bytes(length: int, bits: int, block: int, kept: int | None = None) -> int:
    """Bytes a coded vector of ``length`` values takes on the wire with ``kept`` of them sent (None: all):
    codes, scales, and positions or a mask, whichever is smaller (what ``coded_arrays`` writes)."""
    kept = length if kept is None else kept
    size = code_bytes(kept, bits) if bits < 16 else kept * bits // 8
    if bits < 16:
        size += 4 * -(-kept // block)
    if kept < length:
        size += min(4 * kept, -(-length // 8))
    return size


# ---- clouds ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CodedCloud:
    """A cloud as it travels: (P, 3) codes over its box ``frame`` (low corner, high corner), ``bits`` each."""

    codes: np.ndarray
    frame: np.ndarray
    bits: int


def observed_change(space: ObservedSpace, copy: ObservedSpace | None) -> tuple[ObservedSpace | None, str]:
    """What of observed space ``space`` travels to a receiver holding ``copy``: ``(None, "held")`` when nothing
    changed, ``(change, "delta")`` with the cells that changed (the others unknown: the receiver's cell-wise
    maximum with its copy gives ``space``, as cells only ever rise), or ``(space, "whole")`` without a copy on the
    same lattice inside it. A change is mostly unknown cells: it compresses to a fraction of the grid."""
    if copy is None or copy.cell_m != space.cell_m or not copy.states.size or not space.states.size:
        return space, "whole"
    at = (copy.origin - space.origin).tolist()
    shape = copy.states.shape
    if min(at) < 0 or any(a + n > m for a, n, m in zip(at, shape, space.states.shape)):
        return space, "whole"
    change = space.copy()
    view = change.states[at[0]:at[0] + shape[0], at[1]:at[1] + shape[1], at[2]:at[2] + shape[2]]
    view[view == copy.states] = UNKNOWN
    if shape == space.states.shape and not change.states.any():
        return None, "held"
    return change, "delta"


def encode_cloud(points: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P, 3) points as codes over their own box: the codes (uint8 or uint16, (P, 3)), the box (6,) float32 (low
    corner, high corner) and the points the receiver will decode. A 2 cm voxel cloud of a 4 m object at 16 bits
    is off by at most 0.03 mm; at 8 bits by 8 mm."""
    points = np.asarray(points, np.float32).reshape(-1, 3)
    lo = points.min(axis=0) if len(points) else np.zeros(3, np.float32)
    hi = points.max(axis=0) if len(points) else np.zeros(3, np.float32)
    top = np.float32((1 << bits) - 1)
    span = np.where(hi > lo, hi - lo, np.float32(1)).astype(np.float32)
    codes = np.clip(np.rint((points - lo) / span * top), 0, top).astype(np.uint8 if bits == 8 else np.uint16)
    frame = np.concatenate([lo, hi]).astype(np.float32)
    return codes, frame, decode_cloud(codes, frame, bits)


def decode_cloud(codes: np.ndarray, frame: np.ndarray, bits: int) -> np.ndarray:
    """The float32 points ``encode_cloud`` coded (the same arithmetic at both ends)."""
    lo, hi = frame[:3].astype(np.float32), frame[3:].astype(np.float32)
    with np.errstate(over="ignore", invalid="ignore"):  # corners far apart overflow: read_cloud refuses them
        span = np.where(hi > lo, hi - lo, np.float32(1)).astype(np.float32)
        return (lo + codes.astype(np.float32) / np.float32((1 << bits) - 1) * span).astype(np.float32)


def read_cloud(name: str, bits, arrays: dict[str, np.ndarray], max_points: int) -> np.ndarray:
    """A coded cloud (``NAME.q`` codes, ``NAME.scale`` its box) as float32 points, every field checked."""
    if not isinstance(bits, int) or isinstance(bits, bool) or bits not in (8, 16):
        raise MessageError(f"field {name}_bits: {str(bits)[:40]} (8 or 16; 32 travels as float32)")
    codes = arrays.get(f"{name}.q")
    want = "uint8" if bits == 8 else "uint16"
    if codes is None or codes.dtype.name != want or codes.ndim != 2 or codes.shape[1] != 3 or len(codes) > max_points:
        raise MessageError(f"array {name}.q: expected (n <= {max_points}, 3) {want}")
    frame = _array(arrays, f"{name}.scale", "float32", 6)
    if not np.all(np.isfinite(frame)) or np.any(frame[:3] > frame[3:]):
        raise MessageError(f"array {name}.scale: a box of finite corners, low below high")
    if f"{name}.index" in arrays or f"{name}.mask" in arrays:
        raise MessageError(f"array {name}: a cloud names no positions")
    points = decode_cloud(codes, frame, bits)
    if not np.all(np.isfinite(points)):  # corners far apart overflow their span
        raise MessageError(f"array {name}.scale: the box's span is not finite")
    return points


# ---- on the wire ------------------------------------------------------------------------------------------
def coded_arrays(name: str, coded: CodedVector) -> tuple[dict, dict[str, np.ndarray]]:
    """The scalars and arrays of ``coded`` as message ``name``'s part: the kept entries as positions or as a
    bit mask, whichever is smaller."""
    meta = {"n": coded.length, "bits": coded.bits, "block": coded.block, "base": coded.base, "kept": coded.kept,
            "index": "all"}
    arrays = {f"{name}.q": coded.codes}
    if coded.bits < 16:
        arrays[f"{name}.scale"] = coded.scales
    if coded.index is not None:
        if 4 * len(coded.index) <= -(-coded.length // 8):
            meta["index"], arrays[f"{name}.index"] = "index", coded.index.astype(np.int32)
        else:
            mask = np.zeros(coded.length, bool)
            mask[coded.index] = True
            meta["index"], arrays[f"{name}.mask"] = "mask", np.packbits(mask, bitorder="little")
    return meta, arrays


def coded_parts(name: str) -> tuple[str, ...]:
    """The array names a coded part ``name`` may use."""
    return tuple(f"{name}.{suffix}" for suffix in ("q", "scale", "index", "mask"))


def read_coded(name: str, meta, arrays: dict[str, np.ndarray], length: int | None, max_length: int) -> CodedVector:
    """Part ``name`` as a ``CodedVector``, every field checked (MessageError naming it): a known bit width, a block
    of 1-65536, a length equal to ``length`` (the receiver's width; None: at most ``max_length``), finite
    non-negative scales one a block, the codes' exact byte count, positions increasing and in range or a mask of
    the vector's bits with ``kept`` set, and the base a round number."""
    where = f"field {name}.code"
    if not isinstance(meta, dict) or set(meta) != META_FIELDS:
        raise MessageError(f"{where}: expected the fields {sorted(META_FIELDS)}")
    n, bits, block, base, kept, form = (meta[k] for k in ("n", "bits", "block", "base", "kept", "index"))
    if length is None:  # the receiver leaves it open: no more than the part's bytes can honestly name
        part_bytes = sum(a.nbytes for key, a in arrays.items() if key in set(coded_parts(name)))
        max_length = min(max_length, OPEN_VALUES_PER_BYTE * part_bytes + OPEN_VALUES_SLACK)
    if not is_count(n) or n > (max_length if length is None else length) or (length is not None and n != length):
        raise MessageError(f"{where}: length {str(n)[:40]}, the receiver's vector has "
                           f"{length if length is not None else f'at most {max_length}'}")
    if not isinstance(bits, int) or isinstance(bits, bool) or bits not in BITS:
        raise MessageError(f"{where}: bit width {str(bits)[:40]} (one of {BITS})")
    if not is_count(block) or not 1 <= block <= 1 << 16:
        raise MessageError(f"{where}: block {str(block)[:40]} (1 to 65536 values)")
    if base is not None and not is_count(base):
        raise MessageError(f"{where}: base {str(base)[:40]} is not a round")
    if form not in INDEX_FORMS or not is_count(kept) or kept > n or (form == "all" and kept != n):
        raise MessageError(f"{where}: {str(kept)[:40]} values kept of {n} as {str(form)[:20]!r}")
    if form != "all" and base is None:
        raise MessageError(f"{where}: only a delta may leave entries out")
    known = set(coded_parts(name))
    codes = _array(arrays, f"{name}.q", {4: "uint8", 8: "uint8", 16: "float16", 32: "float32"}[bits],
                   code_bytes(kept, bits) if bits < 16 else kept)
    scales = np.zeros(0, np.float32)
    if bits < 16:
        scales = _array(arrays, f"{name}.scale", "float32", -(-kept // block))
        if not np.all(np.isfinite(scales)) or np.any(scales < 0):
            raise MessageError(f"array {name}.scale: scales must be finite and >= 0")
    elif f"{name}.scale" in arrays:
        raise MessageError(f"array {name}.scale: {bits}-bit values carry no scale")
    if bits >= 16 and not np.all(np.isfinite(codes)):
        raise MessageError(f"array {name}.q: non-finite values")
    index = None
    if form == "index":
        index = _array(arrays, f"{name}.index", "int32", kept)
        if kept and (index[0] < 0 or index[-1] >= n or np.any(np.diff(index) <= 0)):
            raise MessageError(f"array {name}.index: positions must increase and lie in 0..{n - 1}")
    elif form == "mask":
        mask = _array(arrays, f"{name}.mask", "uint8", -(-n // 8))
        bits_set = np.unpackbits(mask, bitorder="little")
        if np.any(bits_set[n:]) or int(bits_set.sum()) != kept:
            raise MessageError(f"array {name}.mask: {int(bits_set.sum())} entries set, {kept} kept")
        index = np.flatnonzero(bits_set[:n]).astype(np.int32)
    unused = [a for a in known - {f"{name}.q", f"{name}.scale"} if a in arrays and
              a != {"index": f"{name}.index", "mask": f"{name}.mask"}.get(form)]
    if unused:
        raise MessageError(f"array {unused[0]}: not a part of a {form!r} code")
    coded = CodedVector(n, bits, block, codes, scales, index, base)
    if not np.all(np.isfinite(dequantise(codes, scales, bits, block, kept))):  # code x scale may overflow
        raise MessageError(f"array {name}.q: its values times their scales are not finite")
    return coded


def _array(arrays: dict[str, np.ndarray], name: str, dtype: str, count: int) -> np.ndarray:
    a = arrays.get(name)
    if a is None:
        raise MessageError(f"array {name}: missing")
    if a.dtype.name != dtype or a.ndim != 1 or len(a) != count:
        raise MessageError(f"array {name}: expected ({count},) {dtype}, got {a.shape} {a.dtype}")
    return a


def vector_wire_bytes(exchange, length: int, has_copy: bool) -> int:
    """Bytes one network vector of ``length`` values takes in a message under ``exchange`` (an ``ExchangeConfig``):
    float32 or float16 whole, or as the codec writes it (a delta's kept share when the peer holds a copy)."""
    c = exchange.codec
    if not c.active:
        return int(length * (2 if exchange.float16 else 4))
    kept = max(1, math.ceil(c.keep * length)) if c.delta and has_copy and c.keep < 1 else None
    return vector_bytes(length, c.bits, c.block, kept)
