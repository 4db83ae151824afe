"""The fields of a decoded message checked against what the receiving team can use (``MessageRules``).

Each check names the field it refuses, so a faulty or hostile sender's message is dropped with a reason
and never reaches ``receive_parameters`` or the renderer (an unknown bank, a NaN frame, a parameter
vector of another width, or a ray count that would allocate without bound).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from mapping.data.poses import rigid_pose_problem
from mapping.model.observed import MAX_CELLS, ObservedSpace, ObservedSpaceError, box_cells
from mapping.team.wire import MessageError, is_count

BANKS = ("object", "structure")
"""The instance network banks a payload may name (``mapping.model.agent``)."""
META_FIELDS = frozenset({"id", "bank", "half", "origin", "version", "caption", "confidence", "cloud", "observed"})
CODE_FIELDS = frozenset({"params_code", "feature_code", "cloud_bits", "observed_code"})
"""Scalars a coded instance adds (``mapping.team.codec``): how its vector, feature and cloud travel; a feature or
observed space left out because the receiver holds it unchanged is ``"feature_code": "held"``,
``"observed_code": "held"``; an observed space of only the cells that changed is ``"observed_code": "delta"``."""
GRID_SLACK_CELLS = 1
"""How many cells an observed grid may start before, or end after, its instance's box on each axis: the box
travels as float32 corners, the grid was made from the float64 box."""


@dataclass(frozen=True)
class MessageRules:
    """What a receiving team can use; a message outside it is refused before anything is applied.

    Attributes:
        num_agents: sender, receiver and frame origins are agent indices below it (None: any).
        param_counts: per bank, the length of one instance's parameter vector (None: any length).
        feature_dim: the caption feature's length (None: any).
        max_rays: poses x rays per pose that one ray message may ask the receiver to render.
        max_image_side: the largest width or height the intrinsics may name.
        max_caption_chars: the longest caption.
        observed_cell_m: the cell an instance's observed space must use (None: any).
        max_observed_cells: the most cells one observed space may announce.
        max_cloud_points: the most points one instance's down-sampled cloud may carry (a 2 cm voxel cloud of a
            20 m x 20 m floor is 1 M): its share of ``message_size.decoded_size_cap``.
        max_message_cells: the most cells all observed spaces of one message may announce together (a byte a
            cell decoded): a box may honestly span ``max_observed_cells``, so 32 instances with 12.7 m boxes
            would still decode to 512 MB; a room's instances at 5 cm announce a few million cells in all (every
            box of a 12 m x 12 m x 3 m room spanning all of it: 3.5 M each), so 2^26 leaves room for about 19
            such boxes.
        max_vector_values: the longest coded vector when ``param_counts`` or ``feature_dim`` leave it open (a
            sparse delta names its length: without a bound, a few bytes could ask for any).
        coded: whether coded messages are read (``mapping.team.codec``): a team whose codec is off refuses them,
            as it holds no copies to resolve them against.
    """

    num_agents: int | None = None
    param_counts: Mapping[str, int] | None = None
    feature_dim: int | None = None
    max_rays: int = 1 << 20
    max_image_side: int = 1 << 14
    max_caption_chars: int = 1000
    observed_cell_m: float | None = None
    max_observed_cells: int = MAX_CELLS
    max_cloud_points: int = 1 << 20
    max_message_cells: int = 1 << 26
    max_vector_values: int = 1 << 24
    coded: bool = True


def team_rules(mapping, exchange, feature_dim: int) -> MessageRules:
    """What a team with these mapping and exchange settings can use (``MappingConfig``, ``ExchangeConfig``): its
    networks' lengths, its caption features' length, its observed spaces' cell, whether its codec is on. The
    channel and the member processes (``remote``) decode with it, so a coded vector's length is always the
    receiver's own."""
    from mapping.model.banks import param_counts  # noqa: PLC0415  (the banks' widths)

    return MessageRules(param_counts=param_counts(mapping), feature_dim=feature_dim,
                        observed_cell_m=mapping.observed_cell_m, coded=exchange.codec.active)


@dataclass(frozen=True)
class InstanceMeta:
    """One instance's scalar fields, checked."""

    id: int
    bank: str
    half: float
    origin: int
    version: int
    caption: str
    confidence: float
    cloud: bool
    observed: bool
    params_code: dict | None = None
    feature_code: dict | str | None = None
    cloud_bits: int | None = None
    observed_code: str | None = None


def count_field(scalars: dict, name: str, upper: int | None = None) -> int:
    """``scalars[name]`` if it is a non-negative integer (at most ``upper``)."""
    value = scalars.get(name)
    if not is_count(value) or (upper is not None and value > upper):
        raise MessageError(f"field {name}: {str(value)[:40]} is not an integer in [0, {upper or 'inf'}]")
    return value


def agent_field(scalars: dict, name: str, rules: MessageRules) -> int:
    """``scalars[name]`` if it is an agent index of the team."""
    return count_field(scalars, name, None if rules.num_agents is None else rules.num_agents - 1)


def finite_number(value, name: str, low: float = -math.inf, high: float = math.inf) -> float:
    """``value`` as a float if it is a finite JSON number in [low, high] (bool is not one)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not low <= value <= high:
        raise MessageError(f"field {name}: {str(value)[:40]} is not a finite number in [{low}, {high}]")
    return float(value)


def checked_array(arrays: dict[str, np.ndarray], name: str, shape: tuple[int | None, ...], floating: bool = True
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


def checked_ids(arrays: dict[str, np.ndarray], name: str) -> np.ndarray:
    """``arrays[name]`` if it is a (n,) array of non-negative integers."""
    a = checked_array(arrays, name, (None,), floating=False)
    if a.dtype.kind not in "iu" or np.any(a < 0):
        raise MessageError(f"array {name}: expected non-negative integers, got {a.dtype}")
    return a.astype(np.int64)


def rigid_poses(poses: np.ndarray) -> np.ndarray:
    """``poses`` ((F, 4, 4)) if every one is a finite rigid transform."""
    for k, pose in enumerate(poses):
        problem = rigid_pose_problem(pose)
        if problem is not None:
            raise MessageError(f"array poses[{k}]: {problem}")
    return poses


def checked_intrinsics(value, rules: MessageRules) -> tuple[float, float, float, float, int, int]:
    """(fx, fy, cx, cy, width, height): positive focal lengths, a centre inside the image, a bounded size."""
    if not (isinstance(value, list) and len(value) == 6):
        raise MessageError(f"field intrinsics: {str(value)[:60]} is not [fx, fy, cx, cy, width, height]")
    width = count_field({"intrinsics width": value[4]}, "intrinsics width", rules.max_image_side)
    height = count_field({"intrinsics height": value[5]}, "intrinsics height", rules.max_image_side)
    if width < 1 or height < 1:
        raise MessageError(f"field intrinsics: an image of {width} x {height} pixels")
    fx = finite_number(value[0], "intrinsics fx", 1e-6)
    fy = finite_number(value[1], "intrinsics fy", 1e-6)
    cx = finite_number(value[2], "intrinsics cx", 0.0, float(width))
    cy = finite_number(value[3], "intrinsics cy", 0.0, float(height))
    return fx, fy, cx, cy, width, height


def instance_meta(k: int, meta, rules: MessageRules) -> InstanceMeta:
    """Instance ``k``'s scalar fields, each checked for type and range."""
    if not isinstance(meta, dict) or not META_FIELDS <= set(meta) <= META_FIELDS | CODE_FIELDS:
        got = sorted(meta)[:12] if isinstance(meta, dict) else type(meta).__name__
        raise MessageError(f"field instances[{k}]: expected the fields {sorted(META_FIELDS)}, got {got}")
    banks = BANKS if rules.param_counts is None else tuple(rules.param_counts)
    if meta["bank"] not in banks:
        raise MessageError(f"field instances[{k}].bank: {str(meta['bank'])[:40]!r} is not one of {banks}")
    caption = meta["caption"]
    if not isinstance(caption, str) or len(caption) > rules.max_caption_chars:
        raise MessageError(f"field instances[{k}].caption: expected text of at most {rules.max_caption_chars} "
                           f"characters, got {type(caption).__name__}")
    for flag in ("cloud", "observed"):
        if not isinstance(meta[flag], bool):
            raise MessageError(f"field instances[{k}].{flag}: expected true or false")
    where = f"instances[{k}]."
    if not rules.coded and set(meta) & CODE_FIELDS:
        raise MessageError(f"field {where}{sorted(set(meta) & CODE_FIELDS)[0]}: a coded instance, and this team's "
                           f"codec is off")
    params_code, feature_code = meta.get("params_code"), meta.get("feature_code")
    if params_code is not None and not isinstance(params_code, dict):
        raise MessageError(f"field {where}params_code: expected the code's fields")
    if feature_code is not None and not (isinstance(feature_code, dict) or feature_code == "held"):
        raise MessageError(f"field {where}feature_code: expected the code's fields or 'held'")
    observed_code, cloud_bits = meta.get("observed_code"), meta.get("cloud_bits")
    if observed_code is not None and (observed_code, meta["observed"]) not in (("held", False), ("delta", True)):
        raise MessageError(f"field {where}observed_code: 'held' (with observed false) or 'delta' (with observed true)")
    if cloud_bits is not None and (cloud_bits not in (8, 16) or isinstance(cloud_bits, bool) or meta["cloud"] is not True):
        raise MessageError(f"field {where}cloud_bits: {str(cloud_bits)[:40]} (8 or 16, with a cloud)")
    origin_limit = None if rules.num_agents is None else rules.num_agents - 1
    return InstanceMeta(_count(meta, "id", where), meta["bank"],
                        finite_number(meta["half"], where + "half", 1e-6, 1e4),
                        _count(meta, "origin", where, origin_limit), _count(meta, "version", where),
                        caption, finite_number(meta["confidence"], where + "confidence", 0.0, 1.0), meta["cloud"],
                        meta["observed"], params_code, feature_code, cloud_bits, observed_code)


def checked_observed(arrays: dict[str, np.ndarray], k: int, lo: np.ndarray, hi: np.ndarray,
                     rules: MessageRules) -> ObservedSpace:
    """Instance ``k``'s observed space (array ``k.observed``: its wire bytes) if it decodes, uses the
    receiver's cell and spans the instance's box [lo, hi] (``GRID_SLACK_CELLS`` of slack for float32 corners);
    lattice indices are compared as Python integers, so no corner can overflow into a match."""
    name = f"{k}.observed"
    data = checked_array(arrays, name, (None,), floating=False)
    if data.dtype != np.uint8:
        raise MessageError(f"array {name}: expected bytes (uint8), got {data.dtype}")
    try:
        space = ObservedSpace.from_bytes(data.tobytes(), rules.observed_cell_m, rules.max_observed_cells)
        first, last = box_cells(lo, hi, space.cell_m)
    except ObservedSpaceError as exc:
        raise MessageError(f"array {name}: {exc}") from None
    origin = space.origin.tolist()
    end = [o + n - 1 for o, n in zip(origin, space.states.shape)]
    if not space.states.size or any(abs(a - b) > GRID_SLACK_CELLS for a, b in zip(origin + end, first + last)):
        raise MessageError(f"array {name}: a grid of cells {origin}..{end} does not match the instance's box "
                           f"(cells {first}..{last})")
    return space


def _count(meta: dict, name: str, where: str, upper: int | None = None) -> int:
    return count_field({where + name: meta[name]}, where + name, upper)
