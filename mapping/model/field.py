"""Instance-level implicit field (paper eq. 5): one small vMAP MLP F_i(x) -> (c, o) per instance,
all instances of a bank evaluated and trained as ONE batched computation.

The network and why it is evaluated with stacked matmuls: ``mapping.model.instance_mlp``.

Why a fixed frame per instance (``mapping.model.instance_frames``): the network sees
``u = (x - frame_centre) / frame_half``, not the box, so a growing box does not stretch what it
learned, and agents sharing a frame hold parameter vectors of the same function (eq. 12, adoption).

Why one flat (N, D) parameter: see ``mapping.model.instance_params``. The forward splits the rows into
per-layer views (one autograd split, whose backward writes all gradients into one (N, D) buffer).
``add_instances`` replaces the parameter tensor: always read ``bank.params`` afresh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, NamedTuple, Sequence

import torch
from torch import Tensor, nn

from mapping.model.encoding import encode_positions, icosahedron_directions
from mapping.model.instance_frames import frame_for_box
from mapping.model.instance_mlp import batched_mlp
from mapping.model.instance_params import init_instance_params, param_layout
from mapping.runtime import resolve_device


@dataclass(frozen=True)
class FieldConfig:
    """Architecture of every instance network in one bank."""

    hidden_width: int = 32
    """W: 32 for objects, 128 for background / structure (vMAP); the mapper sets the structure width
    with ``MappingConfig.structure_width`` (64 by default)."""
    encoding_scale: float = 2.0
    """Box coordinates in [-1, 1] are divided by this before the encoding. vMAP divides metres by 2
    (objects) or 5 (background), i.e. about 2-5 here for 0.5-2 m boxes; 0.5-4 learned a sphere
    equally well (tests), 2 was marginally best."""
    occupancy_sharpness: float = 10.0
    """o = sigmoid(sharpness * raw) (vMAP's ``alpha = raw * 10``)."""
    frame_margin: float = 1.5
    """A new instance's frame half-size is this times its box's largest half-side ..."""
    min_frame_half_m: float = 0.15
    """... and at least this (walls and floors start as strips and grow to the room's size: their
    bank uses a room-sized minimum, so they are rarely refit)."""


OBJECT_FIELD = FieldConfig(hidden_width=32)
STRUCTURE_FIELD = FieldConfig(hidden_width=128, min_frame_half_m=2.5)


class FieldOutput(NamedTuple):
    """Occupancy (*batch,) in (0, 1) and colour (*batch, 3) in (0, 1), or None when not asked for."""

    occupancy: Tensor
    colour: Tensor | None


class InstanceFieldBank(nn.Module):
    """N instance networks of one width, stored as one (N, D) parameter, evaluated with batched matmuls.

    Each instance lives in its own axis-aligned box (``bound_min``, ``bound_max``: (N, 3) buffers,
    not learned: where it is sampled, rendered and meshed) and has its own fixed frame
    (``frame_centre`` (N, 3), ``frame_half`` (N,)): forward maps world points to
    ``(x - centre) / half``, [-1, 1]^3 on the frame's cube. Rows are instance indices ("rows"); the
    caller keeps its own map from instance ids to rows.
    """

    def __init__(self, config: FieldConfig = OBJECT_FIELD, device: str | torch.device = "auto"):
        super().__init__()
        self.config = config
        self.layout = self.network_layout()
        self._sizes = [math.prod(shape) for _, shape in self.layout]
        dev = resolve_device(device)
        self.params = nn.Parameter(torch.zeros(0, sum(self._sizes), device=dev))
        self.register_buffer("bound_min", torch.zeros(0, 3, device=dev))
        self.register_buffer("bound_max", torch.zeros(0, 3, device=dev))
        self.register_buffer("frame_centre", torch.zeros(0, 3, device=dev))
        self.register_buffer("frame_half", torch.zeros(0, device=dev))
        self.register_buffer("directions", icosahedron_directions().to(dev), persistent=False)

    # ---- size and growth -------------------------------------------------------------------------
    @property
    def num_instances(self) -> int:
        return self.params.shape[0]

    @property
    def param_dim(self) -> int:
        """D, the length of one instance's flat parameter vector."""
        return self.params.shape[1]

    @property
    def device(self) -> torch.device:
        return self.params.device

    def add_instances(self, k: int, bound_min: Tensor, bound_max: Tensor,
                      generator: torch.Generator | None = None, frame_centre: Tensor | None = None,
                      frame_half: Tensor | None = None, params: Tensor | None = None) -> list[int]:
        """Append ``k`` instances with (k, 3) world boxes; returns their rows.

        The frame defaults to ``frame_for_box`` of each box; ``params`` ((k, D), e.g. an instance
        adopted from a peer) replaces the fresh initialisation. Existing rows keep their values
        exactly; a ``StackedAdam`` on this bank grows its state on its next step (zero moments, step 0
        for the new rows).
        """
        bmin = torch.as_tensor(bound_min, dtype=torch.float32, device=self.device).reshape(k, 3)
        bmax = torch.as_tensor(bound_max, dtype=torch.float32, device=self.device).reshape(k, 3)
        if not bool(torch.all(bmax > bmin)):
            raise ValueError("every bound_max must exceed bound_min on all three axes")
        centre, half = self.default_frame(bmin, bmax)
        if frame_centre is not None:
            centre = torch.as_tensor(frame_centre, dtype=torch.float32, device=self.device).reshape(k, 3)
        if frame_half is not None:
            half = torch.as_tensor(frame_half, dtype=torch.float32, device=self.device).reshape(k)
        if not bool(torch.all(half > 0)):
            raise ValueError("every frame_half must be positive")
        start = self.num_instances
        if params is None:
            new = self.initial_params(k, generator).to(self.device)
        else:
            new = torch.as_tensor(params, dtype=torch.float32, device=self.device).reshape(k, self.param_dim)
        self.params = nn.Parameter(torch.cat([self.params.detach(), new]))
        self.bound_min = torch.cat([self.bound_min, bmin])
        self.bound_max = torch.cat([self.bound_max, bmax])
        self.frame_centre = torch.cat([self.frame_centre, centre])
        self.frame_half = torch.cat([self.frame_half, half])
        return list(range(start, start + k))

    def network_layout(self) -> list[tuple[str, tuple[int, ...]]]:
        """Names and shapes of one row's parameters (vMAP's network; ``mapping.model.sdf_field`` overrides it)."""
        return param_layout(self.config.hidden_width)

    def initial_params(self, k: int, generator: torch.Generator | None = None) -> Tensor:
        """(k, D) fresh rows on the CPU (vMAP's initialisation)."""
        return init_instance_params(self.config.hidden_width, k, generator)

    def default_frame(self, bound_min: Tensor, bound_max: Tensor) -> tuple[Tensor, Tensor]:
        """This bank's frame for (k, 3) boxes (``frame_for_box`` with the config's margin and minimum)."""
        return frame_for_box(bound_min, bound_max, self.config.frame_margin, self.config.min_frame_half_m)

    def frame_coverage(self, rows: Sequence[int] | Tensor | None = None) -> Tensor:
        """(n,) largest |u| of any box corner in its frame: 1 = the box just fills the frame's cube."""
        sel = slice(None) if rows is None else torch.as_tensor(rows, dtype=torch.long, device=self.device)
        lo, hi, c, h = self.bound_min[sel], self.bound_max[sel], self.frame_centre[sel], self.frame_half[sel]
        return torch.maximum((lo - c).abs(), (hi - c).abs()).amax(-1) / h

    @torch.no_grad()
    def set_frames(self, rows: Sequence[int] | Tensor, frame_centre: Tensor, frame_half: Tensor) -> None:
        """Replace the frames of ``rows`` as they are (no refit: for parameters that were learned in
        that frame, e.g. a peer's; ``instance_frames.refit_frames`` moves a learned network to another
        frame)."""
        rows = torch.as_tensor(rows, dtype=torch.long, device=self.device)
        self.frame_centre[rows] = torch.as_tensor(frame_centre, dtype=torch.float32, device=self.device).reshape(-1, 3)
        self.frame_half[rows] = torch.as_tensor(frame_half, dtype=torch.float32, device=self.device).reshape(-1)

    @torch.no_grad()
    def set_bounds(self, rows: Sequence[int] | Tensor, bound_min: Tensor, bound_max: Tensor) -> None:
        """Replace the boxes of ``rows`` (where they are sampled, rendered and meshed). The frame stays:
        what the network learned does not move or stretch."""
        rows = torch.as_tensor(rows, dtype=torch.long, device=self.device)
        self.bound_min[rows] = torch.as_tensor(bound_min, dtype=torch.float32, device=self.device).reshape(-1, 3)
        self.bound_max[rows] = torch.as_tensor(bound_max, dtype=torch.float32, device=self.device).reshape(-1, 3)

    # ---- per-instance parameter vectors (for sending between agents) -----------------------------
    def get_instance_params(self, row: int) -> Tensor:
        """(D,) copy of one instance's parameters (detached)."""
        return self.params.detach()[row].clone()

    @torch.no_grad()
    def set_instance_params(self, row: int, vector: Tensor) -> None:
        """Overwrite one instance's parameters with a (D,) vector (e.g. received from a peer)."""
        if vector.shape != (self.param_dim,):
            raise ValueError(f"expected a ({self.param_dim},) vector, got {tuple(vector.shape)}")
        self.params[row] = vector.to(self.params)

    def split_params(self, params: Tensor) -> dict[str, Tensor]:
        """Per-layer views (n, *shape) of (n, D) rows (or (*shape) of one (D,) row)."""
        lead = params.shape[:-1]
        pieces = torch.split(params, self._sizes, dim=-1)
        return {name: p.view(*lead, *shape) for (name, shape), p in zip(self.layout, pieces)}

    # ---- evaluation ------------------------------------------------------------------------------
    def to_unit(self, points: Tensor, rows: Tensor | None = None) -> Tensor:
        """World (n, P, 3) -> frame coordinates, [-1, 1]^3 on each instance's frame cube."""
        centre, half = (self.frame_centre, self.frame_half) if rows is None else (self.frame_centre[rows],
                                                                                  self.frame_half[rows])
        return (points - centre[:, None]) / half[:, None, None]

    def forward(self, points: Tensor, rows: Tensor | None = None, with_colour: bool = True) -> FieldOutput:
        """Evaluate every instance (or ``rows``) on its own points, as one batched computation.

        Args:
            points: (n, P, 3) world points, n = N (all instances) or len(rows).
            rows: optional (n,) long instance rows; a row may repeat (see ``query``).
            with_colour: skip the colour head when False (meshing, depth-only rendering).

        Returns:
            occupancy (n, P) and colour (n, P, 3) (None without colour).
        """
        params = self.params if rows is None else self.params.index_select(0, rows)
        if points.shape[0] != params.shape[0] or points.shape[-1] != 3:
            raise ValueError(f"points must be ({params.shape[0]}, P, 3), got {tuple(points.shape)}")
        occupancy, colour = self.evaluate_unit(params, self.to_unit(points, rows), with_colour)
        return FieldOutput(occupancy, colour)

    def evaluate_unit(self, params: Tensor, unit: Tensor, with_colour: bool, logits: bool = False
                      ) -> tuple[Tensor, Tensor | None]:
        """The MLP on (n, P, 3) frame coordinates with (n, D) rows: occupancy (or its logit) and colour.

        Public for ``instance_frames.refit_frames``, which evaluates rows in frames they do not hold."""
        geometry, colour_in = encode_positions(unit, self.directions, self.config.encoding_scale, with_colour)
        return batched_mlp(self.split_params(params), geometry, colour_in, self.config.hidden_width,
                           self.config.occupancy_sharpness, with_colour, logits)

    def query(self, points: Tensor, rows: Tensor, with_colour: bool = True, block_size: int = 4096) -> FieldOutput:
        """Evaluate a ragged set: point m through instance ``rows[m]``, still one batched forward.

        Points are grouped by instance into blocks of at most ``block_size`` (``query_block`` picks the
        size); each block is a batch entry with its instance's parameter row gathered, so padding is
        less than one block per instance however unequal the counts (a wall may own 1000x more samples
        than a cup).

        Args:
            points: (M, 3) world points.
            rows: (M,) long instance rows.

        Returns:
            occupancy (M,) and colour (M, 3) (None without colour).
        """
        m = points.shape[0]
        if m == 0:
            return FieldOutput(points.new_zeros(0), points.new_zeros(0, 3) if with_colour else None)
        order = torch.argsort(rows, stable=True)
        sorted_rows = rows[order]
        counts = torch.bincount(sorted_rows, minlength=self.num_instances)
        # under autograd one block as large as the largest instance, as before: a weight gradient sums over
        # a block's points, so another split would change training in its last bits (and every figure)
        block = (max(1, min(block_size, int(counts.max()))) if torch.is_grad_enabled()
                 else query_block(counts, block_size))
        blocks_per_row = (counts + block - 1) // block
        first_block = torch.cumsum(blocks_per_row, 0) - blocks_per_row
        rank = torch.arange(m, device=points.device) - (torch.cumsum(counts, 0) - counts)[sorted_rows]
        block_id, slot = first_block[sorted_rows] + rank // block, rank % block
        block_rows = torch.repeat_interleave(torch.arange(self.num_instances, device=points.device), blocks_per_row)
        padded = points.new_zeros(len(block_rows), block, 3).index_put((block_id, slot), points[order])
        out = self.forward(padded, rows=block_rows, with_colour=with_colour)
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(m, device=points.device)
        occupancy = out.occupancy[block_id, slot][inverse]
        colour = out.colour[block_id, slot][inverse] if with_colour else None
        return FieldOutput(occupancy, colour)

    def occupancy_fn(self, row: int) -> Callable[[Tensor], Tensor]:
        """``(M, 3) world points -> (M,) occupancy`` of one instance (for meshing)."""
        rows = torch.tensor([row], device=self.device)
        return lambda pts: self.forward(pts.to(self.device)[None], rows=rows, with_colour=False).occupancy[0]

    def colour_fn(self, row: int) -> Callable[[Tensor], Tensor]:
        """``(M, 3) world points -> (M, 3)`` colour of one instance (for mesh vertex colours)."""
        rows = torch.tensor([row], device=self.device)
        return lambda pts: self.forward(pts.to(self.device)[None], rows=rows).colour[0]

    # ---- checkpoints -----------------------------------------------------------------------------
    def get_extra_state(self) -> dict:
        return {"hidden_width": self.config.hidden_width, "encoding_scale": self.config.encoding_scale,
                "occupancy_sharpness": self.config.occupancy_sharpness, "frame_margin": self.config.frame_margin,
                "min_frame_half_m": self.config.min_frame_half_m}

    def set_extra_state(self, state: dict) -> None:
        if state.get("network", "vmap") != "vmap":
            raise ValueError(f"checkpoint holds a {state['network']!r} bank, this is a vMAP occupancy bank")
        if state["hidden_width"] != self.config.hidden_width:
            raise ValueError(f"checkpoint has hidden width {state['hidden_width']}, "
                             f"this bank {self.config.hidden_width}")
        self.config = FieldConfig(**state)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """Load a checkpoint of any number of instances (this bank is resized to it first)."""
        n = state_dict["params"].shape[0]
        if n != self.num_instances:
            self.params = nn.Parameter(torch.zeros(n, self.param_dim, device=self.device))
            self.bound_min = torch.zeros(n, 3, device=self.device)
            self.bound_max = torch.zeros(n, 3, device=self.device)
            self.frame_centre = torch.zeros(n, 3, device=self.device)
            self.frame_half = torch.ones(n, device=self.device)
        return super().load_state_dict(state_dict, strict=strict, assign=assign)


BLOCK_OVERHEAD_POINTS = 128
"""What one more batch entry of ``InstanceFieldBank.query`` costs, counted in padded points."""


def query_block(counts: Tensor, block_size: int = 4096) -> int:
    """Points per batch entry for instances holding ``counts`` points: the power of two from 64 (or the
    largest count, or ``block_size``, when smaller) that pads the fewest points, each entry counted as
    ``BLOCK_OVERHEAD_POINTS`` more. One block as large as the largest instance padded every small
    instance to its size: 4x the points on a map's column grid (``mapping.model.topdown``), 2-3x its time.
    Every point's value is the same whatever the block (tested); used without autograd only."""
    live = counts[counts > 0]
    if len(live) == 0:
        return 1
    top = max(1, min(block_size, int(live.max())))
    candidates = [top] + [2**k for k in range(6, 13) if 2**k < top]
    best, best_cost = top, None
    for size in candidates:
        blocks = (live + size - 1) // size
        cost = int((blocks * size).sum()) + BLOCK_OVERHEAD_POINTS * int(blocks.sum())
        if best_cost is None or cost < best_cost:
            best, best_cost = size, cost
    return best


class LiveRows:
    """Some rows of a bank seen as a bank of their own (compositing needs only these members): the
    live instances of a map whose merged instances keep unused rows."""

    def __init__(self, bank: InstanceFieldBank, rows: Sequence[int]):
        self.bank = bank
        self.rows = torch.as_tensor(list(rows), dtype=torch.long, device=bank.device)

    @property
    def num_instances(self) -> int:
        return len(self.rows)

    @property
    def bound_min(self) -> Tensor:
        return self.bank.bound_min[self.rows]

    @property
    def bound_max(self) -> Tensor:
        return self.bank.bound_max[self.rows]

    def query(self, points: Tensor, rows: Tensor, with_colour: bool = True, block_size: int = 4096) -> FieldOutput:
        """``InstanceFieldBank.query`` with rows numbered within this view."""
        return self.bank.query(points, self.rows[rows], with_colour=with_colour, block_size=block_size)
