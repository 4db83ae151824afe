"""What a parameter message may decode to, checked before any of it is copied out or inflated.

A message's arrays decode to their own bytes (``wire.read_message`` refuses arrays that share bytes), but an
observed grid inflates: 2 bits a cell, zlib-compressed, so 4 kB of zeros announce 2^24 cells (16 MB), and 32
of them made a 1.6 MB message that allocated 560 MB. So each part of each instance gets a share of the
message's cap (``decoded_size_cap``) from the receiving team's settings (``MessageRules``), and a part over its
share is refused, naming it and by how much. No part borrows another's room: a grid is never decoded past
the cells its box spans, however small the instance's cloud.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mapping.team.codec import coded_parts
from mapping.model.observed import GRID_HEADER, ObservedSpaceError, box_cells, grid_header
from mapping.team.message_checks import GRID_SLACK_CELLS, InstanceMeta, MessageRules, instance_meta
from mapping.team.wire import ArrayEntry, MessageError, array_view, read_message

WIDEST_VALUE = 8
"""Bytes of the widest value that travels (float64): a share does not depend on the dtype a sender picked."""
BOX_VALUES = 9
"""An instance's box: low corner, high corner, frame centre."""
POINT_VALUES = 3
"""A cloud point: x, y, z."""
PARTS = ("params", "box", "feature", "cloud", "observed")
"""The arrays one instance may carry (``k.params`` ... ``k.observed``)."""


@dataclass(frozen=True)
class Share:
    """One part of a message: the bytes it decodes to (``used``) and its share of the cap (``allowed``)."""

    part: str
    used: int
    allowed: int
    why: str

    @property
    def over(self) -> int:
        return self.used - self.allowed


def decoded_size_cap(shares: list[Share]) -> int:
    """The most bytes a parameter message may decode to (its arrays and its grids' cells): the sum of its
    instances' shares, so it scales with the message's own instance count, each share set by the receiver:
    8 bytes (float64, the widest) per parameter of the instance's bank and per value of the caption feature
    and of the box, 24 per point of a cloud of at most ``max_cloud_points``, and for an observed grid one byte
    per cell its box spans on the receiver's lattice (with ``GRID_SLACK_CELLS`` a side, at most
    ``max_observed_cells``) plus the wire bytes of those cells packed and compressed. Why: no instance can
    be worth more to the receiver, and only the grid inflates, so it is bounded by its box, not its bytes."""
    return sum(share.allowed for share in shares)


def message_shares(metas: list[InstanceMeta], table: dict[str, ArrayEntry], body: memoryview,
                   rules: MessageRules) -> list[Share]:
    """Every part of the message with its share, read from its array table and its grids' headers only; an
    array no instance claims has a share of 0."""
    shares = [share for k, meta in enumerate(metas) for share in instance_shares(k, meta, table, body, rules)]
    claimed = {name for k in range(len(metas)) for part in PARTS for name in (f"{k}.{part}", *coded_parts(f"{k}.{part}"))}
    return shares + [Share(name[:80], entry.size, 0, f"not a part of the message's {len(metas)} instances")
                     for name, entry in table.items() if name not in claimed]


def check_decoded_size(metas: list[InstanceMeta], table: dict[str, ArrayEntry], body: memoryview,
                       rules: MessageRules) -> int:
    """The bytes the message decodes to; MessageError naming the part furthest over its share and by how much
    (and how many others are over), before anything is decoded."""
    shares = message_shares(metas, table, body, rules)
    used, cap = sum(share.used for share in shares), decoded_size_cap(shares)
    over = sorted((share for share in shares if share.over > 0), key=lambda share: -share.over)
    if over:
        worst = over[0]
        others = ", ".join(f"{s.part} +{s.over}" for s in over[1:4]) + (", ..." if len(over) > 4 else "")
        raise MessageError(f"message over its cap: {worst.part} decodes to {worst.used} bytes, {worst.over} over its "
                           f"share of {worst.allowed} ({worst.why})"
                           + (f"; {len(over) - 1} more parts over their shares ({others})" if others else "")
                           + f"; {used} bytes in all, the cap for {len(metas)} instances is {cap}")
    cells = sum(share.used for share in shares if share.part.endswith(" cells"))
    if cells > rules.max_message_cells:
        raise MessageError(f"message over its cap: its observed spaces announce {cells} cells in all, over the "
                           f"{rules.max_message_cells} one message may carry")
    return used


def size_and_cap(data: bytes, rules: MessageRules) -> tuple[int, int]:
    """What parameter message ``data`` decodes to and its cap, in bytes (how close a message runs to its cap)."""
    _, scalars, table, body = read_message(data)
    metas = scalars.get("instances")
    if not isinstance(metas, list):
        raise MessageError("field instances: expected a list")
    shares = message_shares([instance_meta(k, meta, rules) for k, meta in enumerate(metas)], table, body, rules)
    return sum(share.used for share in shares), decoded_size_cap(shares)


def instance_shares(k: int, meta: InstanceMeta, table: dict[str, ArrayEntry], body: memoryview,
                    rules: MessageRules) -> list[Share]:
    """Instance ``k``'s parts: each array's bytes and, for its grid, the cells its header announces."""
    params = None if rules.param_counts is None else rules.param_counts[meta.bank]
    arrays = [array_share(f"{k}.params", table, params, f"{params} parameters of a {meta.bank} network"),
              array_share(f"{k}.box", table, BOX_VALUES, "a box and a frame centre"),
              array_share(f"{k}.feature", table, rules.feature_dim, f"a caption feature of {rules.feature_dim}"),
              array_share(f"{k}.cloud", table, POINT_VALUES * rules.max_cloud_points if meta.cloud else 0,
                          f"a cloud of at most {rules.max_cloud_points} points" if meta.cloud else "no cloud")]
    if not meta.observed:
        return arrays + [array_share(f"{k}.observed", table, 0, "no observed space")]
    return arrays + grid_shares(k, table, body, rules)


def array_share(name: str, table: dict[str, ArrayEntry], values: int | None, why: str) -> Share:
    """Array ``name``'s bytes against ``values`` of the widest dtype (None: a setting the receiver leaves
    open, bounded by the bytes that arrived, as an array never decodes past them). A coded part
    (``codec.coded_parts``) counts its arrays together; what it decodes to is checked by ``codec.read_coded``
    (its length is the receiver's, or at most ``MessageRules.max_vector_values``)."""
    used = sum(table[n].size for n in (name, *coded_parts(name)) if n in table)
    if values is None:
        return Share(name, used, used, "any length: its own bytes")
    return Share(name, used, WIDEST_VALUE * values, why)


def grid_shares(k: int, table: dict[str, ArrayEntry], body: memoryview, rules: MessageRules) -> list[Share]:
    """Instance ``k``'s grid: its wire bytes, and the cells its header announces against those its box spans."""
    name = f"{k}.observed"
    entry = table.get(name)
    if entry is None or entry.dtype != "uint8" or len(entry.shape) != 1:
        return [Share(name, 0 if entry is None else entry.size, 0, "not grid bytes")]  # refused by name later
    try:
        header = grid_header(array_view(entry, body), rules.observed_cell_m, rules.max_observed_cells)
    except ObservedSpaceError as exc:
        raise MessageError(f"array {name}: {exc}") from None
    cells, why = box_span(k, table, body, header.cell_m, rules.max_observed_cells)
    packed = -(-cells // 4)
    wire = GRID_HEADER.size + packed + packed // 1000 + 64  # zlib's framing: never more than stored blocks
    return [Share(name, entry.size, wire, f"{cells} cells, packed and compressed"),
            Share(f"{name} cells", header.cells, cells, why)]


def box_span(k: int, table: dict[str, ArrayEntry], body: memoryview, cell_m: float, max_cells: int
             ) -> tuple[int, str]:
    """The cells instance ``k``'s box spans on the lattice of ``cell_m`` (with ``GRID_SLACK_CELLS`` a side, at
    most ``max_cells``), read from the body in Python numbers; 0 for a box that is not one."""
    entry = table.get(f"{k}.box")
    if entry is None or entry.shape != (BOX_VALUES,) or np.dtype(entry.dtype).kind != "f":
        return 0, "its box is not 9 floats"
    values = array_view(entry, body).tolist()
    lo, hi = values[:3], values[3:6]
    try:
        first, last = box_cells(lo, hi, cell_m)
    except ObservedSpaceError:
        return 0, "its box is not finite on the lattice"
    spans = [max(b - a + 1 + 2 * GRID_SLACK_CELLS, 0) for a, b in zip(first, last)]
    cells = min(math.prod(spans), max_cells)
    return cells, f"the cells its box spans at {cell_m} m, {GRID_SLACK_CELLS} of slack a side, at most {max_cells}"

