"""The wire format of every message: ``b"OMMSG"``, a version byte, a uint32 header length, a UTF-8 JSON
header (scalars, and for each array its name, dtype, shape and offset), then the arrays' raw little-endian
bytes. A message may travel compressed whole (the codec's lossless stage, ``seal``): ``b"OMMSZ"``, the
method's byte, the uint64 length it inflates to, then the compressed bytes; the length is checked against a
limit before anything inflates, and inflation stops at it.

Bytes that crossed a process or a machine may be anything, so ``read_message`` checks every table entry with
Python integers (no int64 overflow) against the bytes actually there before numpy sees it (the arrays
together at most the body: they decode to no more than arrived), bounds the header's size and nesting, and
raises only ``MessageError``; ``decode_arrays`` then copies them out.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from dataclasses import dataclass

import numpy as np

MAGIC = b"OMMSG"
VERSION = 1
DTYPES = frozenset({"float16", "float32", "float64", "int32", "int64", "uint8", "uint16"})
MAX_HEADER_BYTES = 1 << 21
"""2 MB of JSON: a real header takes about 330 bytes per instance (6,000 instances fit), and JSON of nested
empty lists parses to about 22 times its bytes in Python objects, so this bounds the header's objects to
about 45 MB (16 MB let a header allocate 339 MB)."""
MAX_NDIM = 4
"""No array that travels has more dimensions (poses are (F, 4, 4))."""
MAX_EXTENT = 1 << 40
"""The most elements the non-zero dimensions of one shape may multiply to: numpy refuses a (0, 2^62, 2^62)
array although it is empty."""


ENVELOPE = b"OMMSZ"
LOSSLESS = ("none", "zlib", "zstd")
"""The codec's lossless stages: none, zlib (the standard library's) or zstd (the ``zstandard`` package)."""
MAX_INFLATION = 1024
"""A compressed message may announce at most this many times its own bytes (at least ``MIN_INFLATED``, at most
``MAX_INFLATED``): coded messages compress 1.1-4x, and 250-550x when most instances are still (a delta that
rounds to nothing; a delta of exact zeros travels as no entries); zeros compress 1000x and more, so without a
limit 4 kB could announce gigabytes."""
MIN_INFLATED = 1 << 20
MAX_INFLATED = 1 << 28
"""256 MiB: no message inflates past this, however large (a `fast` round's float32 message is 2.4 MB)."""


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


@dataclass(frozen=True)
class ArrayEntry:
    """One row of a message's array table, checked: its bytes lie inside the body (Python integers)."""

    name: str
    dtype: str
    shape: tuple[int, ...]
    offset: int

    @property
    def size(self) -> int:
        """Bytes of the array (Python integers: no overflow)."""
        return math.prod(self.shape) * np.dtype(self.dtype).itemsize


def seal(data: bytes, method: str, level: int | None = None) -> bytes:
    """``data`` (a packed message) compressed whole by ``method`` (``LOSSLESS``; ``none`` returns it as it is), at
    each library's default level (zlib 6, zstd 3): on a round's coded messages zstd 3 wrote 0.7-2 % fewer bytes
    than zlib 9 in 1/40 of its time (docs/codec.md)."""
    if method == "none":
        return data
    if method == "zlib":
        packed = zlib.compress(data, 6 if level is None else level)
    elif method == "zstd":
        packed = _zstd().ZstdCompressor(level=3 if level is None else level).compress(data)
    else:
        raise ValueError(f"unknown lossless stage {method!r}; choose one of {LOSSLESS}")
    return ENVELOPE + bytes([LOSSLESS.index(method)]) + struct.pack("<Q", len(data)) + packed


def unseal(data: bytes) -> bytes:
    """The packed message a sealed one holds (``data`` itself when it is not sealed); MessageError for an
    unknown method, a length over ``MAX_INFLATION`` times the sealed bytes, or bytes that do not inflate to
    exactly the announced length (inflation stops at it: never more is allocated)."""
    if not data.startswith(ENVELOPE):
        return data
    head = len(ENVELOPE) + 9
    if len(data) < head:
        raise MessageError("truncated message (compressed envelope)")
    method = data[len(ENVELOPE)]
    (size,) = struct.unpack("<Q", data[len(ENVELOPE) + 1:head])
    limit = min(MAX_INFLATED, max(MIN_INFLATED, MAX_INFLATION * len(data)))
    if method == 0 or method >= len(LOSSLESS):
        raise MessageError(f"compressed message of unknown method {method}")
    if size > limit:
        raise MessageError(f"compressed message announces {size} bytes, over {limit} ({MAX_INFLATION} times its "
                           f"{len(data)} bytes, between {MIN_INFLATED} and {MAX_INFLATED})")
    try:
        if LOSSLESS[method] == "zlib":
            inflater = zlib.decompressobj()
            raw = inflater.decompress(data[head:], size + 1)
            complete = inflater.eof and not inflater.unconsumed_tail
        else:
            with _zstd().ZstdDecompressor().stream_reader(data[head:]) as reader:
                raw = reader.read(size + 1)  # at most one byte past the announced length
            complete = True
    except (zlib.error, ValueError, MemoryError) as exc:
        raise MessageError(f"compressed message does not inflate ({type(exc).__name__})") from None
    except Exception as exc:  # noqa: BLE001  (zstandard's own error class)
        raise MessageError(f"compressed message does not inflate ({type(exc).__name__})") from None
    if len(raw) != size or not complete:
        raise MessageError(f"compressed message inflates to {len(raw)}{'+' if len(raw) > size else ''} bytes, "
                           f"it announced {size}")
    if raw.startswith(ENVELOPE):
        raise MessageError("compressed message inside a compressed message")
    return raw


def _zstd():
    try:
        import zstandard  # noqa: PLC0415  (optional: the zstd stage only)
    except ImportError:
        raise ValueError("the zstd lossless stage needs the zstandard package (pip install zstandard); "
                         "zlib needs nothing") from None
    return zstandard


def read_message(data: bytes) -> tuple[str, dict, dict[str, ArrayEntry], memoryview]:
    """Kind, scalars, checked array table and body of ``data`` (inflated first when sealed), nothing decoded
    yet: so that what the arrays would decode to can be checked first. The arrays together hold at most the
    body's bytes (no two may share them: a table that points every entry at the same bytes would decode past
    the message)."""
    data = unseal(bytes(data))
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
    table: dict[str, ArrayEntry] = {}
    for raw in header["arrays"]:
        entry = array_entry(raw, len(body))
        if entry.name in table:
            raise MessageError(f"array {entry.name[:80]} appears twice")
        table[entry.name] = entry
    announced = sum(entry.size for entry in table.values())
    if announced > len(body):
        raise MessageError(f"arrays of {announced} bytes in all, the body holds {len(body)} (arrays share bytes)")
    return header["kind"], header["scalars"], table, body


def array_entry(entry, body_bytes: int) -> ArrayEntry:
    """A table row ``[name, dtype, shape, offset]`` if each is of its type and its bytes lie in the body."""
    if not (isinstance(entry, list) and len(entry) == 4 and isinstance(entry[0], str)):
        raise MessageError(f"corrupt array entry {str(entry)[:80]} (expected [name, dtype, shape, offset])")
    name, dtype, shape, offset = entry
    if not (isinstance(dtype, str) and dtype in DTYPES):
        raise MessageError(f"array {name[:80]}: dtype {str(dtype)[:40]!r} cannot travel (one of {sorted(DTYPES)})")
    if not (isinstance(shape, list) and len(shape) <= MAX_NDIM and all(is_count(d) for d in shape)):
        raise MessageError(f"array {name[:80]}: shape {str(shape)[:80]} is not a list of at most {MAX_NDIM} "
                           f"non-negative integers")
    if math.prod(d for d in shape if d) > MAX_EXTENT:
        raise MessageError(f"array {name[:80]}: shape {str(shape)[:80]} spans more than {MAX_EXTENT} elements")
    if not is_count(offset):
        raise MessageError(f"array {name[:80]}: offset {str(offset)[:40]} is not a non-negative integer")
    checked = ArrayEntry(name, dtype, tuple(shape), offset)
    if offset + checked.size > body_bytes:
        raise MessageError(f"truncated message (array {name[:80]})")
    return checked


def array_view(entry: ArrayEntry, body: memoryview) -> np.ndarray:
    """The array's values as a read-only view of the body (nothing copied)."""
    values = np.frombuffer(body[entry.offset:entry.offset + entry.size], np.dtype(entry.dtype).newbyteorder("<"))
    return values.reshape(entry.shape)


def decode_arrays(table: dict[str, ArrayEntry], body: memoryview) -> dict[str, np.ndarray]:
    """Each array of ``table`` copied out of the body in its native byte order."""
    return {name: array_view(entry, body).astype(entry.dtype) for name, entry in table.items()}


def unpack(data: bytes) -> tuple[str, dict, dict[str, np.ndarray]]:
    """Kind, scalars and arrays of ``data``; MessageError for anything that is not a well-formed message."""
    kind, scalars, table, body = read_message(data)
    return kind, scalars, decode_arrays(table, body)


def is_count(value) -> bool:
    """A JSON non-negative integer (bool is not one)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0
