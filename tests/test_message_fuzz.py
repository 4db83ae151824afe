"""Messages from a faulty or hostile sender: a seeded generator of structured headers (shapes, dtypes,
nesting, every field's type and range) and the specific cases that crashed the receiver before."""

from __future__ import annotations

import copy
import json
import math
import re
import struct
import tracemalloc
import warnings
import zlib
from dataclasses import replace

import numpy as np
import pytest

from mapping.model.banks import param_counts
from mapping.model.agent_config import MappingConfig
from mapping.model.observed import GRID_HEADER, SURFACE, ObservedSpace, ObservedSpaceError, lattice_cell
from mapping.model.observed_map import ObservedMaps
from mapping.team import (Channel, InstancePayload, MessageError, MessageRules, ParameterMessage, RayMessage,
                          from_bytes, to_bytes)
from mapping.team.codec import CodedCloud, encode_cloud, encode_vector
from mapping.team.message_size import size_and_cap
from mapping.team.wire import seal
from mapping.team.messages import DegreeMessage, PointCloudMessage, replay_pixels

COUNTS = param_counts(MappingConfig())
FEATURE_DIM = 8
RULES = MessageRules(num_agents=3, param_counts=COUNTS, feature_dim=FEATURE_DIM, observed_cell_m=0.05)


def _observed() -> ObservedSpace:
    """An observed space over the payloads' box [0, 1]^3 with one surface cell."""
    space = ObservedSpace.empty(0.05)
    space.cover(np.zeros(3), np.ones(3))
    space.mark(np.array([[0.5, 0.5, 0.5]]), SURFACE)
    return space


def _payload(iid: int, bank: str = "object", cloud: bool = True) -> InstancePayload:
    rng = np.random.default_rng(iid)
    return InstancePayload(iid, bank, rng.normal(size=COUNTS[bank]).astype(np.float32), np.zeros(3, np.float32),
                           np.ones(3, np.float32), np.full(3, 0.5, np.float32), 0.75, 1, 2, "a red mug",
                           rng.normal(size=FEATURE_DIM).astype(np.float32), 0.4,
                           rng.normal(size=(20, 3)).astype(np.float32) if cloud else None, _observed())


def _coded_payloads() -> list[InstancePayload]:
    """Coded instances (``mapping.team.codec``): 8 bits whole with a 16-bit cloud, a 4-bit sparse delta named by
    positions, an 8-bit delta named by a mask with its feature and observed space left out (the receiver holds
    them)."""
    rng = np.random.default_rng(5)
    whole, sparse, masked = _payload(5), _payload(6, cloud=False), _payload(7, "structure", cloud=False)
    n = COUNTS["object"]
    whole.params_code, _ = encode_vector(whole.params, 8, 64)
    whole.feature_code, _ = encode_vector(whole.caption_feature, 8, 64)
    sparse.params_code, _ = encode_vector(sparse.params, 4, 32, rng.normal(size=n).astype(np.float32), 2, keep=0.01)
    masked.params_code, _ = encode_vector(masked.params, 8, 64, np.zeros(COUNTS["structure"], np.float32), 1, keep=0.3)
    masked.caption_feature = None
    masked.observed, masked.observed_code = None, "held"
    codes, frame, whole.cloud = encode_cloud(whole.cloud, 16)
    whole.cloud_code = CodedCloud(codes, frame, 16)
    return [whole, sparse, masked]


def _valid_messages() -> list[bytes]:
    pose = np.eye(4, dtype=np.float32)
    pose[:3, 3] = [1.0, 2.0, 0.5]
    return [to_bytes(ParameterMessage(0, 1, 3, [_payload(3), _payload(4, "structure", cloud=False)], degree=2)),
            to_bytes(RayMessage(0, 1, 3, np.stack([pose, np.eye(4, dtype=np.float32)]),
                                (100.0, 100.0, 80.0, 60.0, 160, 120), 7, 32)),
            to_bytes(PointCloudMessage(0, 1, 3, np.zeros((5, 3), np.float32))),
            to_bytes(DegreeMessage(0, 1, 3, np.array([3, 4]), np.array([1, 2]), np.array([1, 2]))),
            to_bytes(ParameterMessage(0, 1, 3, _coded_payloads(), degree=2))]


def _split(data: bytes) -> tuple[dict, bytes]:
    start = len(b"OMMSG") + 1
    (n,) = struct.unpack("<I", data[start:start + 4])
    return json.loads(data[start + 4:start + 4 + n]), data[start + 4 + n:]


def _join(header, body: bytes, raw: bytes | None = None) -> bytes:
    blob = raw if raw is not None else json.dumps(header, allow_nan=True).encode()
    return b"OMMSG" + bytes([1]) + struct.pack("<I", len(blob)) + blob + body


HOSTILE = [None, True, False, -1, 0, 1, 2, 3, 7, 2**31, 2**32, 2**63, 2**64, 2**70, -2**70, 0.5, -0.0, 1e308,
           -1e308, math.nan, math.inf, -math.inf, "", "x", "object", "structure", "global", "a" * 5000, [], [1],
           [2**70, 3], [2**32, 2**32, 3], [1, 1, 1, 1, 1, 1, 1], {}, {"a": 1}, [[[[[]]]]], ["float32"]]


def _deep(depth: int):
    value: list = []
    for _ in range(depth):
        value = [value]
    return value


def _mutate(header: dict, body: bytes, rng: np.random.Generator) -> bytes:
    """One structured mutation: a scalar, an instance field, an array entry, the nesting, or the body."""
    h = copy.deepcopy(header)
    pick = rng.integers(7)
    value = HOSTILE[rng.integers(len(HOSTILE))]
    if pick == 0:  # a top-level scalar
        key = list(h["scalars"])[rng.integers(len(h["scalars"]))]
        h["scalars"][key] = value
    elif pick == 1 and h["scalars"].get("instances"):  # an instance's field
        meta = h["scalars"]["instances"][rng.integers(len(h["scalars"]["instances"]))]
        meta[list(meta)[rng.integers(len(meta))]] = value
    elif pick == 2 and h["arrays"]:  # an array table entry: name, dtype, shape or offset
        entry = h["arrays"][rng.integers(len(h["arrays"]))]
        entry[rng.integers(4)] = value
    elif pick == 3 and h["arrays"]:  # a shape made large, long or negative
        entry = h["arrays"][rng.integers(len(h["arrays"]))]
        entry[2] = [int(d) for d in rng.choice([0, 1, 3, 4, 9, 2**31, 2**40, 2**62, -1], size=rng.integers(0, 7))]
    elif pick == 4:  # nesting far deeper than JSON's recursion limit, or a different layout
        where = rng.integers(3)
        if where == 0:
            return _join(None, body, raw=b"[" * 100_000 + b"]" * 100_000)
        h["scalars" if where == 1 else "arrays"] = _deep(int(rng.integers(1, 50)))
    elif pick == 5:  # the body cut or grown
        cut = int(rng.integers(0, len(body) + 1))
        return _join(h, body[:cut] if rng.random() < 0.7 else body + bytes(int(rng.integers(1, 64))))
    else:  # bytes of the header or body flipped
        data = bytearray(_join(h, body))
        for _ in range(int(rng.integers(1, 8))):
            data[int(rng.integers(len(data)))] = int(rng.integers(256))
        return bytes(data)
    return _join(h, body)


def _assert_usable(message) -> None:
    """What a delivered message must be for the receiver: every field inside the rules."""
    assert 0 <= message.sender < 3 and 0 <= message.receiver < 3
    if isinstance(message, ParameterMessage):
        for inst in message.instances:
            assert inst.bank in COUNTS and len(inst.params) == COUNTS[inst.bank]
            assert np.all(np.isfinite(inst.params)) and math.isfinite(inst.frame_half) and inst.frame_half > 0
            assert 0.0 <= inst.confidence <= 1.0 and isinstance(inst.caption, str)
            assert isinstance(inst.instance_id, int)
            assert inst.caption_feature is None or len(inst.caption_feature) == FEATURE_DIM
            if inst.params_code is not None:  # what the receiver allocates is the network's length
                assert inst.params_code.length == COUNTS[inst.bank] and inst.params_code.bits in (4, 8, 16, 32)
            if inst.observed is not None:  # on the receiver's lattice, over the instance's box
                assert inst.observed.cell_m == 0.05 and inst.observed.states.size <= RULES.max_observed_cells
                first = inst.observed.cells_of(inst.bound_lo[None].astype(np.float64))[0]
                assert np.all(np.abs(inst.observed.origin - first) <= 1)
    if isinstance(message, RayMessage):
        assert len(message.poses) * message.rays_per_pose <= RULES.max_rays
        replay_pixels(message)  # bounded


def _decoded_usable(data: bytes) -> bool:
    """Whether ``data`` decodes (then it must be usable: ``_assert_usable``) rather than being refused."""
    try:
        message = from_bytes(data, RULES)
    except MessageError:
        return False
    _assert_usable(message)
    return True


def test_ten_thousand_structured_hostile_messages_are_refused_or_usable_and_never_raise_else():
    rng = np.random.default_rng(2026)
    valid = [_split(data) for data in _valid_messages()]
    kinds = ["params", "rays", "points", "degrees", "params"]
    refused = delivered = 0
    for case in range(10_000):
        k = int(rng.integers(len(valid)))
        data = _mutate(*valid[k], rng)
        usable = _decoded_usable(data)
        refused, delivered = refused + (not usable), delivered + usable
        channel = Channel(3, rules=RULES)
        with warnings.catch_warnings():  # one refusal warning per refused message
            warnings.simplefilter("ignore")
            d = channel.transmit_bytes(0, 1, kinds[k], data)  # never raises: refused means dropped
        assert d.status in ("delivered", "dropped"), case
        assert (d.message is None) == (d.status == "dropped")
        if d.message is not None:
            _assert_usable(d.message)
    assert refused > 7_000 and delivered > 100  # most mutations break a rule; some leave a usable message


def test_two_thousand_hostile_sealed_messages_are_refused_or_usable():
    """The lossless stage's envelope mutated: its method, announced length, compressed bytes cut or flipped,
    and valid messages (coded ones too) sealed after a structured mutation: refused or usable, never else,
    and nothing inflates past its limit."""
    rng = np.random.default_rng(63)
    valid = [_split(data) for data in (_valid_messages()[0], _valid_messages()[-1])]
    refused = delivered = 0
    for case in range(2000):
        header, body = valid[int(rng.integers(2))]
        data = seal(_mutate(header, body, rng) if rng.random() < 0.5 else _join(header, body),
                    ("zlib", "zstd")[int(rng.integers(2))])
        pick = rng.integers(4)
        if pick == 0:  # the method
            data = data[:5] + bytes([int(rng.integers(256))]) + data[6:]
        elif pick == 1:  # the announced length
            sizes = [0, 1, 100, len(data), 2**20, 2**40, 2**64 - 1]
            data = data[:6] + struct.pack("<Q", sizes[int(rng.integers(len(sizes)))]) + data[14:]
        elif pick == 2:  # the compressed bytes cut or flipped
            data = bytearray(data[:int(rng.integers(14, len(data) + 1))])
            for _ in range(int(rng.integers(0, 4))):
                if len(data) > 14:
                    data[int(rng.integers(14, len(data)))] = int(rng.integers(256))
            data = bytes(data)
        usable = _decoded_usable(data)
        refused, delivered = refused + (not usable), delivered + usable
    assert refused > 1000 and delivered > 50, (refused, delivered)


def _set_meta(field: str, value):
    def change(header: dict) -> dict:
        header["scalars"]["instances"][0][field] = value
        return header
    return change


@pytest.mark.parametrize("field, value, error", [
    ("bank", "global", "instances\\[0\\].bank: 'global' is not one of"),
    ("half", math.nan, "instances\\[0\\].half: nan is not a finite number"),
    ("confidence", math.inf, "instances\\[0\\].confidence: inf"),
    ("id", "x", "instances\\[0\\].id: x is not an integer"),
    ("caption", ["a", "mug"], "instances\\[0\\].caption: expected text"),
    ("origin", 5, "instances\\[0\\].origin: 5 is not an integer in \\[0, 2\\]"),
    ("cloud", 1, "instances\\[0\\].cloud: expected true or false"),
])
def test_each_instance_field_is_checked_and_the_message_dropped(field, value, error):
    header, body = _split(_valid_messages()[0])
    data = _join(_set_meta(field, value)(header), body)
    with pytest.raises(MessageError, match=error):
        from_bytes(data, RULES)
    with pytest.warns(UserWarning, match="refused"):
        assert Channel(3, rules=RULES).transmit_bytes(0, 1, "params", data).status == "dropped"


def test_sizes_that_overflow_int64_nesting_and_unbounded_rays_are_refused():
    header, body = _split(_valid_messages()[0])
    for shape in ([2**70, 3], [2**32, 2**32, 3], [2**62, 2**62]):
        h = copy.deepcopy(header)
        h["arrays"][0][2] = shape
        with pytest.raises(MessageError, match="truncated|shape"):
            from_bytes(_join(h, body), RULES)
    with pytest.raises(MessageError, match="corrupt message header"):
        from_bytes(_join(None, body, raw=b"[" * 100_000 + b"]" * 100_000))
    rays, rays_body = _split(_valid_messages()[1])
    rays["scalars"]["rays_per_pose"] = 10**15
    with pytest.raises(MessageError, match="rays_per_pose"):
        from_bytes(_join(rays, rays_body), RULES)
    params = ParameterMessage(0, 1, 0, [_payload(3)])
    params.instances[0].params = params.instances[0].params[:5]
    with pytest.raises(MessageError, match="0.params: 5 values, a object network has"):
        from_bytes(to_bytes(params), RULES)
    twice = ParameterMessage(0, 1, 0, [_payload(3), _payload(3)])
    with pytest.raises(MessageError, match="appears twice"):
        from_bytes(to_bytes(twice), RULES)


def test_a_message_naming_another_link_or_kind_is_dropped():
    data = _valid_messages()[0]  # sender 0, receiver 1
    with pytest.warns(UserWarning, match="sender, receiver: 0 -> 1 on the link 2 -> 1"):
        assert Channel(3, rules=RULES).transmit_bytes(2, 1, "params", data).status == "dropped"
    with pytest.warns(UserWarning, match="a params message sent as rays"):
        assert Channel(3, rules=RULES).transmit_bytes(0, 1, "rays", data).status == "dropped"


@pytest.mark.parametrize("pose_change, error", [
    (lambda p: p.__setitem__((0, 0), 5.0), "rotation"),
    (lambda p: p.__setitem__((0, 1), 1e30), "rotation has an entry beyond 1"),
    (lambda p: p.__setitem__((1, 3), 1e30), "over 100000 m"),
    (lambda p: p.__setitem__((2, 2), -1.0), "reflection"),
])
def test_ray_messages_with_non_rigid_or_huge_poses_are_refused(pose_change, error):
    pose = np.eye(4, dtype=np.float64)
    pose_change(pose)
    message = RayMessage(0, 1, 0, pose[None].astype(np.float32), (100.0, 100.0, 80.0, 60.0, 160, 120), 7, 4)
    with pytest.raises(MessageError, match=error):
        from_bytes(to_bytes(message), RULES)


# ---- messages bounded as a whole: a cap on what a message decodes to, checked before anything inflates ----

class _Announced:
    """Stands in for an observed space on the sending side: ``to_bytes`` returns the given grid bytes."""

    def __init__(self, data: bytes):
        self.data = data

    def to_bytes(self) -> bytes:
        return self.data


def _grid_bytes(origin, shape, cells: bytes | None = None, cell_m: float = 0.05) -> bytes:
    """A grid's wire bytes: its header, then ``cells`` (default: every cell unknown, 2 bits a cell) compressed."""
    packed = bytes(-(-math.prod(shape) // 4)) if cells is None else cells
    return GRID_HEADER.pack(cell_m, *origin, *shape) + zlib.compress(packed, 6)


def _with_grids(grids: list[bytes]) -> bytes:
    """A valid parameter message (boxes [0, 1]^3) whose instances carry ``grids`` as their observed spaces."""
    payloads = [_payload(3 + k) for k in range(len(grids))]
    for payload, grid in zip(payloads, grids):
        payload.observed = _Announced(grid)
    return to_bytes(ParameterMessage(0, 1, 0, payloads))


def _refused_within(data: bytes, rules: MessageRules, peak_mb: float) -> MessageError:
    """The MessageError ``data`` raises, asserting that decoding it never held more than ``peak_mb`` MB."""
    tracemalloc.start()
    try:
        with pytest.raises(MessageError) as refused:
            from_bytes(data, rules)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < peak_mb * 1e6, f"{peak / 1e6:.1f} MB held while refusing"
    return refused.value


def test_thirty_two_grids_past_their_boxes_are_refused_before_one_is_inflated():
    empty = _grid_bytes((0, 0, 0), (256, 256, 256))  # 2^24 cells (16 MB decoded) in 4 kB, over boxes of 21^3 cells
    data = _with_grids([empty] * 32)
    assert len(data) < 2_000_000
    error = _refused_within(data, RULES, peak_mb=8)  # each grid would have been 16 MB, 537 MB in all
    assert re.search(r"over its cap: \d+\.observed cells decodes to 16777216 bytes, 16765049 over its share of "
                     r"12167 \(the cells its box spans", str(error))
    assert "for 32 instances" in str(error)
    with pytest.warns(UserWarning, match="refused: message over its cap"):
        assert Channel(3, rules=RULES).transmit_bytes(0, 1, "params", data).status == "dropped"


def test_thirty_two_grids_as_large_as_their_boxes_are_refused_by_the_message_wide_cell_limit():
    """The review's message: 32 instances whose 12.7 m boxes honestly span 2^24 cells each (512 MB decoded)."""
    empty = _grid_bytes((-1, -1, -1), (256, 256, 256))
    payloads = [_payload(3 + k) for k in range(32)]
    for payload in payloads:
        payload.observed, payload.bound_hi = _Announced(empty), np.full(3, 12.7, np.float32)
    data = to_bytes(ParameterMessage(0, 1, 0, payloads))
    error = _refused_within(data, RULES, peak_mb=8)
    assert f"announce {32 * 256 ** 3} cells in all, over the {1 << 26} one message may carry" in str(error)
    assert from_bytes(_with_grids([_grid_bytes((-1, -1, -1), (23, 23, 23))] * 32), RULES)  # small boxes pass


def test_arrays_that_share_the_bodys_bytes_are_refused():
    header, body = _split(_valid_messages()[0])
    name, dtype, shape, offset = header["arrays"][0]
    header["arrays"] += [[f"alias{k}", dtype, shape, offset] for k in range(1000)]  # 1000 views of one array
    with pytest.raises(MessageError, match="arrays of \\d+ bytes in all, the body holds \\d+"):
        from_bytes(_join(header, body), RULES)


@pytest.mark.parametrize("corner", [-2**63, 2**63 - 1, -(2**40) - 1])
def test_grid_origins_beyond_the_lattice_are_refused_without_overflow(corner):
    data = _with_grids([_grid_bytes((corner, 0, 0), (21, 21, 21))])
    with pytest.raises(MessageError, match=r"0\.observed: observed space: origin \[-?\d+, 0, 0\] out of bounds"):
        from_bytes(data, RULES)
    with pytest.raises(ObservedSpaceError, match="origin"):
        ObservedSpace.from_bytes(_grid_bytes((corner, 0, 0), (21, 21, 21)))
    with pytest.warns(UserWarning, match="refused: array 0.observed"):
        assert Channel(3, rules=RULES).transmit_bytes(0, 1, "params", data).status == "dropped"


@pytest.mark.parametrize("inflated, error", [
    (2_000_000, r"0\.observed: observed space: 2317 bytes of cells \(cut\), expected 2316"),  # fits its share
    (16_000_000, r"0\.observed decodes to \d+ bytes, \d+ over its share of 3165 \(12167 cells, packed and compr"),
])
def test_a_compressed_grid_that_would_inflate_past_its_cells_is_refused_unexpanded(inflated, error):
    data = _with_grids([_grid_bytes((0, 0, 0), (21, 21, 21), cells=bytes(inflated))])
    assert re.search(error, str(_refused_within(data, RULES, peak_mb=4)))


def _largest_grid(lo: float = 0.0, hi: float = 1.0, extra: int = 0) -> ObservedSpace:
    """The largest grid the box [lo, hi]^3 allows (one cell of slack a side), ``extra`` cells longer on x."""
    first, last = lattice_cell(lo, 0.05) - 1, lattice_cell(hi, 0.05) + 1
    n = last - first + 1
    space = ObservedSpace(0.05, np.full(3, first, np.int64), np.zeros((n + extra, n, n), np.uint8))
    space.mark(np.array([[0.5, 0.5, 0.5]]), SURFACE)
    return space


def test_a_message_just_under_its_cap_is_accepted_and_one_slab_more_is_refused():
    rules = replace(RULES, max_cloud_points=40)
    wide = _payload(3)  # every part at its share: float64 network and feature, 40 points, the largest grid
    wide.params, wide.caption_feature = wide.params.astype(np.float64), wide.caption_feature.astype(np.float64)
    wide.cloud, wide.observed = np.zeros((40, 3), np.float32), _largest_grid()
    data = to_bytes(ParameterMessage(0, 1, 0, [wide]))
    used, cap = size_and_cap(data, rules)
    grid_share = GRID_HEADER.size + 3042 + 3 + 64  # 23^3 cells packed four a byte, with zlib's framing
    assert cap - used == 9 * 4 + 40 * 3 * 4 + grid_share - len(wide.observed.to_bytes())  # float32 box and cloud
    assert from_bytes(data, rules).instances[0].observed.states.shape == (23, 23, 23)
    wide.observed = _largest_grid(extra=1)
    with pytest.raises(MessageError, match=r"0\.observed cells decodes to 12696 bytes, 529 over its share of 12167"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 0, [wide])), rules)
    wide.observed, wide.cloud = _largest_grid(), np.zeros((81, 3), np.float32)  # 972 bytes: 81 float64 points
    with pytest.raises(MessageError, match=r"0\.cloud decodes to 972 bytes, 12 over its share of 960 \(a cloud of "
                                           r"at most 40 points\)"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 0, [wide])), rules)


def test_a_peers_grid_that_cannot_join_the_own_one_is_left_out_with_a_warning():
    far = _payload(3)
    far.bound_lo, far.bound_hi = np.full(3, 10_000.0, np.float32), np.full(3, 10_001.0, np.float32)
    far.observed = _largest_grid(10_000.0, 10_001.0)
    arrived = from_bytes(to_bytes(ParameterMessage(0, 1, 0, [far])), RULES).instances[0].observed  # a valid grid
    maps = ObservedMaps(0.05)
    maps.add(3, _observed())
    before = maps.get(3).copy()
    with pytest.warns(UserWarning, match="observed space of instance 3 left out: .* exceeds 16777216"):
        maps.add(3, arrived)  # together 200,000 x 23 x 23 cells: no plain ValueError from an arrived message
    assert np.array_equal(maps.get(3).states, before.states) and np.array_equal(maps.get(3).origin, before.origin)
