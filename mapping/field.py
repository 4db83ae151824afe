"""Instance-level implicit field (paper eq. 5): one small vMAP MLP F_i(x) -> (c, o) per instance,
all instances of a bank evaluated and trained as ONE batched computation.

Network (vMAP's ``OccupancyMap``), hidden width W (32 for objects, 128 for structure: walls, floor,
ceiling)::

    x (world) -> u in [-1, 1]^3 (the instance's box) -> t = u / encoding_scale
    encoding: a_j = d_j . t on 21 fixed directions d_j; sin(pi 2^k a_j) for k = 0..5 (sin only, as
              vMAP's UniDirsEmbed); geometry input = [bands 0-3, t]   4*21 + 3 = 87
                                    colour extra   = bands 4-5         2*21     = 42
    geometry: 87 -> W, W -> W, skip [h, geometry input] (W+87) -> W, W -> W, W -> 1 (ReLU between)
    colour:   [h, colour extra] (W+42) -> W -> 3, sigmoid
    occupancy o = sigmoid(10 * raw)

Why stacked ``bmm``/``baddbmm`` and not ``torch.func.functional_call`` + ``vmap``: vmap lowers each
Linear to the same batched matmuls plus its own batching overhead, and cannot merge layers; on this
2-core CPU its forward + backward took 1.15-1.4x as long as the hand-batched form, and a Python loop
over instances (one module and one AdamW each) 1.2-18x as long as the whole batched step
(``benchmarks/bench_field.py`` measures all three). The layers are stored split and merged for speed
(see ``param_layout``): the first layer and the skip layer's encoding rows are one (87, 2W) matmul;
the occupancy output rides as one extra column of the colour layer (a 1-column matmul runs at 2-3
GFLOP/s); and no gradient is computed for the encodings (vMAP's concatenated skip and colour inputs
would waste 12 % of the backward work on them).

Why a fixed frame per instance: the network sees ``u = (x - frame_centre) / frame_half`` with the
centre and half-size fixed when the instance is created (from its first box), not the box itself. A
box that grows as the instance is seen more (``set_bounds``) therefore does not stretch what the
network learned, and two agents whose instances share one frame hold parameter vectors of the SAME
function, which is what parameter consistency (eq. 12) and adoption need. ``refit_frames`` moves rows
to a new frame by distillation (the box outgrew the frame, or the team agreed on another frame).

Why one flat (N, D) parameter: each instance is one row, so sending an instance's parameters between
agents, the parameter-consistency loss (eq. 12) and DiNNO/DSGD mixing are row operations, growth is a
row concatenation, and Adam is one fused pass. The forward splits the rows into per-layer views (one
autograd split, whose backward writes all gradients into one (N, D) buffer). ``add_instances``
replaces the parameter tensor: always read ``bank.params`` afresh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, NamedTuple, Sequence

import torch
from torch import Tensor, nn

N_DIRECTIONS = 21
N_BANDS = 6  # frequencies 2^0 .. 2^5 (vMAP: n_unidir_funcs = 5)
GEOMETRY_BANDS = 4  # the first four feed the geometry trunk, the last two only the colour head
GEOMETRY_INPUT_DIM = 3 + GEOMETRY_BANDS * N_DIRECTIONS  # 87
COLOUR_INPUT_DIM = (N_BANDS - GEOMETRY_BANDS) * N_DIRECTIONS  # 42
LOGIT_LIMIT = 30.0
"""Occupancy logits are clamped to +-30: beyond, o is 1 or < 1e-13 in float32 anyway, and the sigmoid's
gradient would underflow into denormal floats (slow on many CPUs) that then spread through backward."""


def resolve_device(device: str | torch.device = "auto") -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; anything else is passed to ``torch.device``."""
    if isinstance(device, str) and device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def icosahedron_directions() -> Tensor:
    """(21, 3) float32 unit vectors: the 6 vertex axes and 15 edge-midpoint axes of a regular icosahedron.

    The same well-spread set as vMAP's fixed projection table, derived here instead of tabulated; each
    axis once (an antipode only flips the sign of the sine), sorted for a stable order.
    """
    phi = (1.0 + 5.0**0.5) / 2.0
    verts = []
    for a in (-1.0, 1.0):
        for b in (-phi, phi):
            verts += [(0.0, a, b), (a, b, 0.0), (b, 0.0, a)]
    v = torch.tensor(verts, dtype=torch.float64)  # 12 vertices, edge length 2
    i, j = torch.triu_indices(12, 12, offset=1)
    is_edge = ((v[i] - v[j]).norm(dim=1) - 2.0).abs() < 1e-9
    dirs = torch.cat([v, (v[i[is_edge]] + v[j[is_edge]]) / 2.0])
    dirs = dirs / dirs.norm(dim=1, keepdim=True)
    first = dirs[torch.arange(len(dirs)), (dirs.abs() > 1e-9).to(torch.int64).argmax(dim=1)]
    dirs = dirs * first.sign()[:, None]  # one representative per axis: first non-zero component > 0
    dirs = torch.unique(dirs.round(decimals=6), dim=0)
    assert dirs.shape == (N_DIRECTIONS, 3)
    return dirs.float()


def encode_positions(unit_coords: Tensor, directions: Tensor, scale: float) -> tuple[Tensor, Tensor]:
    """vMAP's directional sine encoding, split into the geometry input and the colour-only extra.

    Speed on CPU (measured 1.7x faster than the direct form): sin(2^k a) for k >= 1 comes from sin a
    and cos a by the double-angle recursion (one multiply and one fused multiply-add per band instead
    of a sine of a large argument; no less accurate, since the float32 argument 2^5 pi a itself
    carries ~1e-5 error), and the features are written feature-major into one (..., 129, P) buffer,
    so every elementwise pass runs over long contiguous rows; the outputs are transposed views of it,
    which the matmuls read at no cost.

    Args:
        unit_coords: (..., P, 3) box coordinates (inside the box in [-1, 1]).
        directions: (21, 3) unit projection directions.
        scale: coordinates are divided by it first (vMAP: obj_scale).

    Returns:
        (..., P, 87) geometry input [sin bands 0-3, t] and (..., P, 42) colour extra [sin bands 4-5],
        where t = u / scale and band k is sin(pi 2^k d_j . t).
    """
    n_dir, n_col = N_DIRECTIONS, COLOUR_INPUT_DIM
    eye = torch.eye(3, dtype=unit_coords.dtype, device=unit_coords.device)
    projection = torch.cat([directions.to(unit_coords) * math.pi, eye]) / scale  # (24, 3): band-0 phases and t
    phase_t = projection @ unit_coords.transpose(-1, -2)  # (..., 24, P)
    features = unit_coords.new_empty(*phase_t.shape[:-2], n_col + GEOMETRY_INPUT_DIM, phase_t.shape[-1])
    features[..., -3:, :] = phase_t[..., n_dir:, :]
    rows = [n_col + k * n_dir for k in range(GEOMETRY_BANDS)] + [k * n_dir for k in range(N_BANDS - GEOMETRY_BANDS)]
    phase = phase_t[..., :n_dir, :]
    s = torch.sin(phase, out=features[..., rows[0] : rows[0] + n_dir, :])
    c2 = torch.cos(phase).mul_(2.0)  # 2 cos a
    two = torch.full((), 2.0, dtype=phase.dtype, device=phase.device)
    for k in range(1, N_BANDS):
        s_next = torch.mul(s, c2, out=features[..., rows[k] : rows[k] + n_dir, :])  # sin 2a = sin a * 2 cos a
        if k + 1 < N_BANDS:
            c2 = torch.addcmul(two, s, s, value=-4.0)  # 2 cos 2a = 2 - 4 sin^2 a
        s = s_next
    return features[..., n_col:, :].transpose(-1, -2), features[..., :n_col, :].transpose(-1, -2)


def param_layout(width: int) -> list[tuple[str, tuple[int, ...]]]:
    """Names and shapes of one instance's parameters, in their order inside the flat row.

    vMAP's layers are stored split and merged for speed: the skip layer (W+87 -> W) is ``w_skip``
    (its hidden rows) plus the right half of ``w_enc`` (its encoding rows, beside the first layer's
    87 -> W); the colour layer (W+42 -> W) is the left part of ``w_head`` (hidden rows) plus
    ``w_col_enc``; the occupancy output (W -> 1) is the last column of ``w_head``.
    """
    w, g, c = width, GEOMETRY_INPUT_DIM, COLOUR_INPUT_DIM
    return [
        ("w_enc", (g, 2 * w)),  # [first layer | skip layer's encoding rows]
        ("b_enc", (2 * w,)),  # [first layer bias | skip layer bias]
        ("w_mid1", (w, w)),
        ("b_mid1", (w,)),
        ("w_skip", (w, w)),
        ("w_mid2", (w, w)),
        ("b_mid2", (w,)),
        ("w_head", (w, w + 1)),  # [colour layer's hidden rows | occupancy output]
        ("b_head", (w + 1,)),
        ("w_col_enc", (c, w)),
        ("w_rgb", (w, 3)),
        ("b_rgb", (3,)),
    ]


def mlp_flops_per_point(width: int) -> int:
    """Forward FLOPs of one point, 2 * in * out summed over the vMAP layers (biases and activations ignored)."""
    w, g, c = width, GEOMETRY_INPUT_DIM, COLOUR_INPUT_DIM
    layers = [(g, w), (w, w), (w + g, w), (w, w), (w, 1), (w + c, w), (w, 3)]
    return sum(2 * i * o for i, o in layers)


def frame_for_box(bound_min: Tensor, bound_max: Tensor, margin: float = 1.0, min_half_m: float = 0.0
                  ) -> tuple[Tensor, Tensor]:
    """The frame of (k, 3) boxes: their centres (k, 3) and half-sizes (k,) = max(margin x largest
    half-side, min_half_m).

    Isotropic (one half-size for all axes), so a box growing along one axis never changes how the
    network sees the others. The margin leaves room to grow: the agent moves an instance to a larger
    frame (a refit) only when its box reaches ``MappingConfig.frame_limit`` of the frame's half-size.
    """
    half = (((bound_max - bound_min) / 2.0).amax(-1) * margin).clamp_min(min_half_m)
    return (bound_min + bound_max) / 2.0, half


@dataclass(frozen=True)
class FieldConfig:
    """Architecture of every instance network in one bank."""

    hidden_width: int = 32
    """W: 32 for objects, 128 for background / structure (vMAP)."""
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


def init_instance_params(width: int, k: int, generator: torch.Generator | None = None) -> Tensor:
    """(k, D) float32 initial rows, drawn on the CPU so a seed gives the same network on any device.

    vMAP's init: Xavier-normal weights, PyTorch's default uniform(+-1/sqrt(fan_in)) biases; split
    layers are drawn whole (their fan-in includes both halves) and then cut.
    """
    g, c = GEOMETRY_INPUT_DIM, COLOUR_INPUT_DIM

    def weight(fan_in: int, fan_out: int) -> Tensor:
        std = math.sqrt(2.0 / (fan_in + fan_out))
        return torch.randn(k, fan_in, fan_out, generator=generator) * std

    def bias(fan_in: int, fan_out: int) -> Tensor:
        return (torch.rand(k, fan_out, generator=generator) * 2.0 - 1.0) / math.sqrt(fan_in)

    w = width
    w_in, b_in = weight(g, w), bias(g, w)
    w_mid1, b_mid1 = weight(w, w), bias(w, w)
    w_skip, b_skip = weight(w + g, w), bias(w + g, w)  # rows: [hidden, encoding] as vMAP's cat
    w_mid2, b_mid2 = weight(w, w), bias(w, w)
    w_occ, b_occ = weight(w, 1), bias(w, 1)
    w_col, b_col = weight(w + c, w), bias(w + c, w)
    w_rgb, b_rgb = weight(w, 3), bias(w, 3)
    parts = {
        "w_enc": torch.cat([w_in, w_skip[:, w:]], dim=2), "b_enc": torch.cat([b_in, b_skip], dim=1),
        "w_mid1": w_mid1, "b_mid1": b_mid1, "w_skip": w_skip[:, :w], "w_mid2": w_mid2, "b_mid2": b_mid2,
        "w_head": torch.cat([w_col[:, :w], w_occ], dim=2), "b_head": torch.cat([b_col, b_occ], dim=1),
        "w_col_enc": w_col[:, w:], "w_rgb": w_rgb, "b_rgb": b_rgb,
    }
    return torch.cat([parts[name].reshape(k, -1) for name, _ in param_layout(width)], dim=1)


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
        self.layout = param_layout(config.hidden_width)
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
            new = init_instance_params(self.config.hidden_width, k, generator).to(self.device)
        else:
            new = torch.as_tensor(params, dtype=torch.float32, device=self.device).reshape(k, self.param_dim)
        self.params = nn.Parameter(torch.cat([self.params.detach(), new]))
        self.bound_min = torch.cat([self.bound_min, bmin])
        self.bound_max = torch.cat([self.bound_max, bmax])
        self.frame_centre = torch.cat([self.frame_centre, centre])
        self.frame_half = torch.cat([self.frame_half, half])
        return list(range(start, start + k))

    def default_frame(self, bound_min: Tensor, bound_max: Tensor) -> tuple[Tensor, Tensor]:
        """This bank's frame for (k, 3) boxes (``frame_for_box`` with the config's margin and minimum)."""
        return frame_for_box(bound_min, bound_max, self.config.frame_margin, self.config.min_frame_half_m)

    def frame_coverage(self, rows: Sequence[int] | Tensor | None = None) -> Tensor:
        """(n,) largest |u| of any box corner in its frame: 1 = the box just fills the frame's cube."""
        sel = slice(None) if rows is None else torch.as_tensor(rows, dtype=torch.long, device=self.device)
        lo, hi, c, h = self.bound_min[sel], self.bound_max[sel], self.frame_centre[sel], self.frame_half[sel]
        return torch.maximum((lo - c).abs(), (hi - c).abs()).amax(-1) / h

    def refit_frames(self, rows: Sequence[int], frame_centre: Tensor, frame_half: Tensor, steps: int = 150,
                     points: int = 1024, lr: float = 3e-3, generator: torch.Generator | None = None) -> float:
        """Move ``rows`` to new frames by distillation: fit each row, in its new frame, to what it
        rendered in its old one (occupancy logits and colour at random points of its box), starting
        from its old parameters. Returns the final mean absolute occupancy difference.

        Needed when a box outgrows its frame (``frame_coverage`` too large) or when the team agrees on
        another instance's frame; callers reset the rows' optimiser state afterwards.
        """
        if len(rows) == 0:
            return 0.0
        idx = torch.as_tensor(rows, dtype=torch.long, device=self.device)
        centre = torch.as_tensor(frame_centre, dtype=torch.float32, device=self.device).reshape(len(rows), 3)
        half = torch.as_tensor(frame_half, dtype=torch.float32, device=self.device).reshape(len(rows))
        lo, hi = self.bound_min[idx], self.bound_max[idx]
        gen = generator if generator is not None and generator.device == self.device else None
        old_params = self.params.detach()[idx].clone()
        old_centre, old_half = self.frame_centre[idx].clone(), self.frame_half[idx].clone()

        def sample() -> Tensor:
            u = torch.rand(len(rows), points, 3, device=self.device, generator=gen)
            return lo[:, None] + (hi - lo)[:, None] * u

        def evaluate(params: Tensor, c: Tensor, h: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
            return self._evaluate(params, (x - c[:, None]) / h[:, None, None], with_colour=True, logits=True)

        student = nn.Parameter(old_params.clone())
        optimiser = torch.optim.Adam([student], lr=lr)
        diff = 0.0
        for _ in range(steps):
            x = sample()
            with torch.no_grad():
                target_logit, target_colour = evaluate(old_params, old_centre, old_half, x)
            logit, colour = evaluate(student, centre, half, x)
            target_occ, occ = torch.sigmoid(target_logit), torch.sigmoid(logit)
            loss = (occ - target_occ).abs().mean() + 0.2 * ((colour - target_colour).abs().mean(-1)
                                                            * target_occ).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            diff = float((occ - target_occ).abs().mean().detach())
        with torch.no_grad():
            self.params[idx] = student.detach()
            self.frame_centre[idx] = centre
            self.frame_half[idx] = half
        return diff

    @torch.no_grad()
    def set_frames(self, rows: Sequence[int] | Tensor, frame_centre: Tensor, frame_half: Tensor) -> None:
        """Replace the frames of ``rows`` as they are (no refit: for parameters that were learned in
        that frame, e.g. a peer's; ``refit_frames`` moves a learned network to another frame)."""
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
        occupancy, colour = self._evaluate(params, self.to_unit(points, rows), with_colour)
        return FieldOutput(occupancy, colour)

    def _evaluate(self, params: Tensor, unit: Tensor, with_colour: bool, logits: bool = False
                  ) -> tuple[Tensor, Tensor | None]:
        """The MLP on (n, P, 3) frame coordinates with (n, D) rows: occupancy (or its logit) and colour."""
        geometry, colour_in = encode_positions(unit, self.directions, self.config.encoding_scale)
        p = self.split_params(params)
        w = self.config.hidden_width
        b = {name: t.unsqueeze(1) for name, t in p.items() if name.startswith("b_")}  # (n, 1, out)
        # torch.split (one backward concatenation), not slicing (a zero-filled gradient per slice).
        pre_in, pre_skip = torch.split(torch.baddbmm(b["b_enc"], geometry, p["w_enc"]), w, dim=-1)
        h = torch.relu(pre_in)
        h = torch.relu_(torch.baddbmm(b["b_mid1"], h, p["w_mid1"]))
        h = torch.relu_(torch.baddbmm(pre_skip, h, p["w_skip"]))  # skip layer (W+87 -> W)
        h = torch.relu_(torch.baddbmm(b["b_mid2"], h, p["w_mid2"]))
        pre_col, raw = torch.split(torch.baddbmm(b["b_head"], h, p["w_head"]), w, dim=-1)  # colour part | raw
        logit = self._logit(raw.squeeze(-1))
        occupancy = logit if logits else torch.sigmoid(logit)
        if not with_colour:
            return occupancy, None
        c = torch.relu_(torch.baddbmm(pre_col, colour_in, p["w_col_enc"]))  # colour layer (W+42 -> W)
        return occupancy, torch.sigmoid(torch.baddbmm(b["b_rgb"], c, p["w_rgb"]))

    def _logit(self, raw: Tensor) -> Tensor:
        """sharpness * raw, clamped to +-LOGIT_LIMIT."""
        return (self.config.occupancy_sharpness * raw).clamp(-LOGIT_LIMIT, LOGIT_LIMIT)

    def looped_forward(self, points: Tensor, with_colour: bool = True) -> FieldOutput:
        """The same as ``forward`` with a Python loop over instances and vMAP's concatenating layers
        (reference for tests and the benchmark; not for training)."""
        w = self.config.hidden_width
        occupancies, colours = [], []
        for i in range(self.num_instances):
            p = self.split_params(self.params[i])
            unit = self.to_unit(points[i : i + 1], torch.tensor([i], device=self.device))[0]
            geometry, colour_in = encode_positions(unit, self.directions, self.config.encoding_scale)
            b_in, b_skip = p["b_enc"][:w], p["b_enc"][w:]
            w_in, w_skip = p["w_enc"][:, :w], torch.cat([p["w_skip"], p["w_enc"][:, w:]])
            w_col, b_col = torch.cat([p["w_head"][:, :w], p["w_col_enc"]]), p["b_head"][:w]
            w_occ, b_occ = p["w_head"][:, w:], p["b_head"][w:]
            h = torch.relu(geometry @ w_in + b_in)
            h = torch.relu(h @ p["w_mid1"] + p["b_mid1"])
            h = torch.relu(torch.cat([h, geometry], -1) @ w_skip + b_skip)
            h = torch.relu(h @ p["w_mid2"] + p["b_mid2"])
            occupancies.append(torch.sigmoid(self._logit((h @ w_occ + b_occ)[:, 0])))
            if with_colour:
                c = torch.relu(torch.cat([h, colour_in], -1) @ w_col + b_col)
                colours.append(torch.sigmoid(c @ p["w_rgb"] + p["b_rgb"]))
        occupancy = torch.stack(occupancies) if occupancies else points.new_zeros(0, points.shape[1])
        colour = (torch.stack(colours) if colours else points.new_zeros(0, points.shape[1], 3)) if with_colour else None
        return FieldOutput(occupancy, colour)

    def query(self, points: Tensor, rows: Tensor, with_colour: bool = True, block_size: int = 4096) -> FieldOutput:
        """Evaluate a ragged set: point m through instance ``rows[m]``, still one batched forward.

        Points are grouped by instance into blocks of at most ``block_size``; each block is a batch
        entry with its instance's parameter row gathered, so padding is at most one block per
        instance however unequal the counts (a wall may own 1000x more samples than a cup).

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
        block = max(1, min(block_size, int(counts.max())))
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
