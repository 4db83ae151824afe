"""The wire format of every message: ``b"OMMSG"``, a version byte, a uint32 header length, a UTF-8 JSON
header (scalars, and for each array its name, dtype, shape and offset), then the arrays' raw little-endian
bytes.

Bytes that crossed a process or a machine may be anything, so ``unpack`` checks every table entry with
Python integers (no int64 overflow) against the bytes actually there before numpy sees it, bounds the
header's size and nesting, and raises only ``MessageError``.
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np

MAGIC = b"OMMSG"
VERSION = 1
DTYPES = frozenset({"float16", "float32", "float64", "int32", "int64", "uint8"})
MAX_HEADER_BYTES = 1 << 24
"""16 MB of JSON: far above any real header (a few kB per instance)."""
MAX_NDIM = 4
"""No array that travels has more dimensions (poses are (F, 4, 4))."""


class MessageError(ValueError):
    """Bytes that are not a message of this version (truncated, corrupt, of another kind, or with a field
    outside what the receiving team can use)."""


def pack(kind: str, scalars: dict, arrays: dict[str, np.ndarray]) -> bytes:
    """``kind``, its JSON ``scalars`` and its named ``arrays`` as one byte string."""
    table, blobs, offset = [], [], 0
    for name, array in arrays.items():
        a = np.ascontiguousarray(array)
        if a.dtype.name not in DTYPES:
            raise TypeError(f"array {name}: dtype {a.dtype} cannot travel")
        blob = a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
        table.append([name, a.dtype.name, list(a.shape), offset])
        blobs.append(blob)
        offset += len(blob)
    header = json.dumps({"kind": kind, "scalars": scalars, "arrays": table}, separators=(",", ":")).encode()
    return MAGIC + bytes([VERSION]) + struct.pack("<I", len(header)) + header + b"".join(blobs)


def unpack(data: bytes) -> tuple[str, dict, dict[str, np.ndarray]]:
    """Kind, scalars and arrays of ``data``; MessageError for anything that is not a well-formed message."""
    if len(data) < len(MAGIC) + 5 or not data.startswith(MAGIC):
        raise MessageError("not an OpenMulti message (bad magic)")
    if data[len(MAGIC)] != VERSION:
        raise MessageError(f"message version {data[len(MAGIC)]}, this code reads {VERSION}")
    start = len(MAGIC) + 1
    (n,) = struct.unpack("<I", data[start:start + 4])
    if n > MAX_HEADER_BYTES:
        raise MessageError(f"message header of {n} bytes (at most {MAX_HEADER_BYTES})")
    if start + 4 + n > len(data):
        raise MessageError(f"truncated message (header of {n} bytes)")
    try:
        header = json.loads(data[start + 4:start + 4 + n].decode())
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise MessageError(f"corrupt message header ({type(exc).__name__})") from None
    if not (isinstance(header, dict) and isinstance(header.get("kind"), str)
            and isinstance(header.get("scalars"), dict) and isinstance(header.get("arrays"), list)):
        raise MessageError("corrupt message header (expected kind, scalars and arrays)")
    body = memoryview(data)[start + 4 + n:]
    arrays = {}
    for entry in header["arrays"]:
        if not (isinstance(entry, list) and len(entry) == 4 and isinstance(entry[0], str)):
            raise MessageError(f"corrupt array entry {str(entry)[:80]} (expected [name, dtype, shape, offset])")
        name, dtype, shape, offset = entry
        if name in arrays:
            raise MessageError(f"array {name[:80]} appears twice")
        if not (isinstance(dtype, str) and dtype in DTYPES):
            raise MessageError(f"array {name[:80]}: dtype {str(dtype)[:40]!r} cannot travel (one of {sorted(DTYPES)})")
        if not (isinstance(shape, list) and len(shape) <= MAX_NDIM and all(is_count(d) for d in shape)):
            raise MessageError(f"array {name[:80]}: shape {str(shape)[:80]} is not a list of at most {MAX_NDIM} "
                               f"non-negative integers")
        if not is_count(offset):
            raise MessageError(f"array {name[:80]}: offset {str(offset)[:40]} is not a non-negative integer")
        size = math.prod(shape) * np.dtype(dtype).itemsize  # Python integers: no overflow
        if offset + size > len(body):
            raise MessageError(f"truncated message (array {name[:80]})")
        dt = np.dtype(dtype).newbyteorder("<")
        arrays[name] = np.frombuffer(body[offset:offset + size], dtype=dt).reshape(shape).astype(dtype)
    return header["kind"], header["scalars"], arrays


def is_count(value) -> bool:
    """A JSON non-negative integer (bool is not one)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
