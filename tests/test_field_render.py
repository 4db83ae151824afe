"""Instance field bank, StackedAdam, ray sampling, occupancy rendering, compositing and data losses."""

from __future__ import annotations

import io
import math
import subprocess
import sys

import pytest
import torch

from mapping.data.frame import Intrinsics
from mapping.model.encoding import COLOUR_INPUT_DIM, GEOMETRY_INPUT_DIM, encode_positions, icosahedron_directions
from mapping.model.field import FieldConfig, FieldOutput, InstanceFieldBank
from mapping.model.field_reference import looped_forward
from mapping.model.instance_frames import refit_frames
from mapping.model.optim import AdamConfig, StackedAdam, reference_adamw
from mapping.runtime import resolve_device, same_device
from mapping.model.losses import DataLossWeights, data_loss, depth_loss, masked_mean, occupancy_loss
from mapping.model.render import (
    CompositeConfig,
    RayBundle,
    SamplerConfig,
    camera_rays,
    composite_instances,
    image_rays,
    ray_aabb,
    render_image,
    render_occupancy,
    sample_along_rays,
)

RADIUS_M = 0.3
INTRINSICS = Intrinsics.from_fov(48, 36, 60.0)


@pytest.fixture(autouse=True)
def one_thread():
    """Single-threaded torch: on a busy 2-core machine two OpenMP threads can stall each other badly."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def look_at(eye: list[float]) -> torch.Tensor:
    """(4, 4) camera-to-world, OpenCV axes, looking at the origin with z up."""
    eye_t = torch.tensor(eye, dtype=torch.float32)
    z = -eye_t / eye_t.norm()
    x = torch.linalg.cross(z, torch.tensor([0.0, 0.0, 1.0]))
    x = x / x.norm()
    pose = torch.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, torch.linalg.cross(z, x), z, eye_t
    return pose


def sphere_depth(rays: RayBundle, centre=(0.0, 0.0, 0.0), radius: float = RADIUS_M) -> tuple[torch.Tensor, torch.Tensor]:
    """Analytic camera depth of a sphere along rays (z-unit directions): (depth, hit)."""
    o = rays.origins - torch.tensor(centre)
    d = rays.directions
    a, b, c = (d * d).sum(-1), 2 * (o * d).sum(-1), (o * o).sum(-1) - radius**2
    disc = b * b - 4 * a * c
    t = (-b - disc.clamp_min(0).sqrt()) / (2 * a)
    hit = (disc > 0) & (t > 0)
    return torch.where(hit, t, torch.zeros_like(t)), hit


class AnalyticField:
    """Duck-typed bank: instance i is a solid sphere (occupancy 1 inside) with a constant colour."""

    def __init__(self, centres: list[tuple[float, float, float]], radii: list[float], pad: float = 0.05):
        self.centres = torch.tensor(centres)
        self.radii = torch.tensor(radii)
        self.bound_min = self.centres - self.radii[:, None] - pad
        self.bound_max = self.centres + self.radii[:, None] + pad
        self.colours = torch.rand(len(radii), 3, generator=torch.Generator().manual_seed(3))

    @property
    def num_instances(self) -> int:
        return len(self.radii)

    def query(self, points, rows, with_colour=True, block_size=4096):
        inside = (points - self.centres[rows]).norm(dim=-1) < self.radii[rows]
        return FieldOutput(inside.float(), self.colours[rows] if with_colour else None)


def make_bank(n: int = 4, width: int = 32, seed: int = 0) -> InstanceFieldBank:
    bank = InstanceFieldBank(FieldConfig(hidden_width=width), device="cpu")
    g = torch.Generator().manual_seed(seed)
    centres = torch.rand(n, 3, generator=g) * 3.0
    bank.add_instances(n, centres - 0.4, centres + torch.tensor([0.4, 0.6, 0.3]), generator=g)
    return bank


def points_in_boxes(bank: InstanceFieldBank, p: int, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    lo, hi = bank.bound_min[:, None], bank.bound_max[:, None]
    return lo + torch.rand(bank.num_instances, p, 3, generator=g) * (hi - lo) * 1.2 - 0.1 * (hi - lo)


def train_steps(bank: InstanceFieldBank, opt: StackedAdam, steps: int, seed: int = 2) -> None:
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        points = points_in_boxes(bank, 64, seed=int(torch.randint(1000, (1,), generator=g)))
        occupancy, colour = bank(points)
        opt.zero_grad()
        (occupancy.mean() + colour.square().mean()).backward()
        opt.step()


# ---- field ------------------------------------------------------------------------------------------
def test_directions_and_encoding_dims():
    dirs = icosahedron_directions()
    assert dirs.shape == (21, 3)
    assert torch.allclose(dirs.norm(dim=1), torch.ones(21))
    cosines = (dirs @ dirs.T).abs() - torch.eye(21)
    assert cosines.max() < 0.86  # no two parallel: well spread
    u = torch.rand(500, 3) * 2 - 1
    geometry, colour = encode_positions(u, dirs, 2.0)
    assert geometry.shape == (500, GEOMETRY_INPUT_DIM) == (500, 87) and colour.shape == (500, COLOUR_INPUT_DIM) == (500, 42)
    phase = (u.double() / 2.0) @ dirs.double().T * math.pi
    exact = torch.sin(phase[:, None, :] * 2.0 ** torch.arange(6, dtype=torch.float64)[:, None]).float()
    assert torch.allclose(geometry[:, :84], exact[:, :4].flatten(1), atol=5e-5)
    assert torch.allclose(colour, exact[:, 4:].flatten(1), atol=5e-5)
    assert torch.equal(geometry[:, 84:], u / 2.0)
    geometry_only, none = encode_positions(u, dirs, 2.0, with_colour=False)
    assert none is None and torch.equal(geometry_only, geometry)  # the same geometry input, bit for bit


def test_occupancy_without_colour_is_the_same_bit_for_bit():
    bank = make_bank(5)
    points = points_in_boxes(bank, 300)
    with torch.no_grad():
        assert torch.equal(bank(points).occupancy, bank(points, with_colour=False).occupancy)


def test_batched_forward_and_gradients_match_loop():
    bank = make_bank(5)
    points = points_in_boxes(bank, 37)
    occ, col = bank(points)
    (occ.sum() + (col * torch.linspace(0, 1, 3)).sum()).backward()
    grad_batched = bank.params.grad.clone()
    bank.params.grad = None
    occ_loop, col_loop = looped_forward(bank, points)
    (occ_loop.sum() + (col_loop * torch.linspace(0, 1, 3)).sum()).backward()
    assert occ.shape == (5, 37) and col.shape == (5, 37, 3)
    assert torch.allclose(occ, occ_loop, atol=1e-5) and torch.allclose(col, col_loop, atol=1e-5)
    assert torch.allclose(grad_batched, bank.params.grad, atol=1e-5)
    assert occ.min() > 0 and occ.max() < 1


def test_rows_and_packed_query_match_forward():
    bank = make_bank(4)
    points = points_in_boxes(bank, 20)
    full = bank(points)
    sub = bank(points[[2, 0]], rows=torch.tensor([2, 0]))
    assert torch.allclose(sub.occupancy, full.occupancy[[2, 0]], atol=1e-6)
    # Ragged: a different number of points per instance, shuffled, in blocks of 3.
    keep = torch.tensor([0] * 20 + [1] * 3 + [3] * 11)
    index = torch.cat([torch.arange(20), torch.arange(3), torch.arange(11)])
    perm = torch.randperm(len(keep), generator=torch.Generator().manual_seed(0))
    rows, pts = keep[perm], points[keep[perm], index[perm]]
    packed = bank.query(pts, rows, block_size=3)
    assert torch.allclose(packed.occupancy, full.occupancy[rows, index[perm]], atol=1e-6)
    assert torch.allclose(packed.colour, full.colour[rows, index[perm]], atol=1e-6)
    assert torch.allclose(bank.occupancy_fn(3)(points[3]), full.occupancy[3], atol=1e-6)


def test_deterministic_init_and_device():
    assert torch.equal(make_bank(3, seed=7).params, make_bank(3, seed=7).params)
    assert not torch.equal(make_bank(3, seed=7).params, make_bank(3, seed=8).params)
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert InstanceFieldBank(device="cpu").num_instances == 0


def test_devices_compare_by_what_they_are():
    """``cuda`` and ``cuda:0`` are one device: the refit's seeded generator is used on either spelling."""
    assert same_device(torch.device("cpu"), torch.device("cpu"))
    assert not same_device(torch.device("cpu"), torch.device("cuda", 0))
    assert same_device(torch.device("cuda"), torch.device("cuda", torch.cuda.current_device()
                                                           if torch.cuda.is_available() else 0))
    if torch.cuda.is_available():
        assert resolve_device("cuda").index is not None
    else:
        with pytest.raises(ValueError, match="no CUDA device"):
            resolve_device("cuda")


def test_get_set_instance_params_round_trip():
    bank, other = make_bank(3, seed=0), make_bank(3, seed=1)
    vector = other.get_instance_params(1)
    assert vector.shape == (bank.param_dim,) == (11300,)  # vMAP's W=32 network
    bank.set_instance_params(2, vector)
    assert torch.equal(bank.get_instance_params(2), vector)
    points = points_in_boxes(other, 16)
    bank.set_bounds([2], other.bound_min[1:2], other.bound_max[1:2])
    bank.set_frames([2], other.frame_centre[1:2], other.frame_half[1:2])
    assert torch.allclose(bank(points[[1]], rows=torch.tensor([2])).occupancy, other(points)[0][1:2])
    with pytest.raises(ValueError):
        bank.set_instance_params(0, vector[:-1])


def test_a_growing_box_does_not_stretch_the_learned_function():
    bank = make_bank(2, seed=3)
    points = points_in_boxes(bank, 32)
    before = bank(points).occupancy
    bank.set_bounds([0, 1], bank.bound_min - 0.3, bank.bound_max + torch.tensor([0.5, 0.1, 0.2]))
    assert torch.equal(bank(points).occupancy, before)
    assert float(bank.frame_coverage([0])[0]) > 1.0


def test_refit_moves_a_network_to_another_frame_keeping_its_shape():
    bank = make_bank(1, seed=4)
    points = points_in_boxes(bank, 4000, seed=7)
    before = bank(points).occupancy.detach()
    centre, half = bank.frame_centre.clone() + 0.2, bank.frame_half.clone() * 1.5
    diff = refit_frames(bank, [0], centre, half, steps=300, generator=torch.Generator().manual_seed(0))
    assert torch.allclose(bank.frame_centre, centre) and torch.allclose(bank.frame_half, half)
    after = bank(points).occupancy.detach()
    assert diff < 0.1
    assert float((after - before).abs().mean()) < 0.1
    assert float(((after > 0.5) == (before > 0.5)).float().mean()) > 0.9


def test_structure_width_bank():
    bank = InstanceFieldBank(FieldConfig(hidden_width=128), device="cpu")
    bank.add_instances(2, torch.zeros(2, 3), torch.ones(2, 3), generator=torch.Generator().manual_seed(0))
    points = torch.rand(2, 10, 3)
    occ, col = bank(points)
    assert occ.shape == (2, 10) and col.shape == (2, 10, 3)
    occ_loop, col_loop = looped_forward(bank, points)
    assert torch.allclose(occ, occ_loop, atol=1e-5) and torch.allclose(col, col_loop, atol=1e-5)


# ---- optimiser ---------------------------------------------------------------------------------------
def test_add_instances_keeps_parameters_and_moments_bit_exact():
    bank = make_bank(3)
    opt = StackedAdam(bank, AdamConfig(lr=1e-2, weight_decay=0.0))
    train_steps(bank, opt, 4)
    before = [t.clone() for t in (bank.params.detach(), opt.exp_avg, opt.exp_avg_sq, opt.steps)]
    rows = bank.add_instances(2, torch.zeros(2, 3), torch.ones(2, 3), generator=torch.Generator().manual_seed(5))
    assert rows == [3, 4]
    assert torch.equal(bank.params.detach()[:3], before[0])
    opt._sync()
    for now, old in zip((opt.exp_avg, opt.exp_avg_sq, opt.steps), before[1:]):
        assert torch.equal(now[:3], old) and not now[3:].any()
    # The new rows start Adam from step 0: the first update of each weight is lr * sign(grad).
    start = bank.params.detach().clone()
    train_steps(bank, opt, 1, seed=9)
    assert opt.steps.tolist() == [5, 5, 5, 1, 1]
    moved = (bank.params.detach()[3:] - start[3:]).abs()
    has_grad = bank.params.grad[3:].abs() > 1e-6
    assert torch.allclose(moved[has_grad], torch.full_like(moved[has_grad], 1e-2), rtol=1e-2)


def test_step_only_some_rows_and_reference_arithmetic():
    bank = make_bank(4)
    opt = StackedAdam(bank, AdamConfig(lr=1e-2))
    train_steps(bank, opt, 2)
    occupancy, _ = bank(points_in_boxes(bank, 8))
    opt.zero_grad()
    occupancy.sum().backward()
    before = bank.params.detach().clone()
    moments = opt.exp_avg.clone(), opt.exp_avg_sq.clone(), opt.steps.clone()
    opt.step(rows=[1, 3])
    after = bank.params.detach()
    assert torch.equal(after[[0, 2]], before[[0, 2]]) and not torch.equal(after[1], before[1])
    assert opt.steps.tolist() == [2, 3, 2, 3]
    # The fused kernel agrees with the reference arithmetic.
    p, (m, v, s) = before[[1, 3]].clone(), (t[[1, 3]].clone() for t in moments)
    g = bank.params.grad[[1, 3]]
    reference_adamw(list(p), list(g), list(m), list(v), list(s), opt.config)
    assert torch.allclose(p, after[[1, 3]], atol=1e-7, rtol=0)
    assert torch.allclose(m, opt.exp_avg[[1, 3]], atol=1e-9)


def test_state_dict_round_trip_exact():
    bank = make_bank(3)
    opt = StackedAdam(bank)
    train_steps(bank, opt, 3)
    buffer = io.BytesIO()
    torch.save({"bank": bank.state_dict(), "opt": opt.state_dict()}, buffer)
    buffer.seek(0)
    saved = torch.load(buffer, weights_only=False)
    restored = InstanceFieldBank(FieldConfig(hidden_width=32, encoding_scale=7.0), device="cpu")
    restored.load_state_dict(saved["bank"])
    restored_opt = StackedAdam(restored)
    restored_opt.load_state_dict(saved["opt"])
    assert restored.config == bank.config
    for a, b in [(restored.params, bank.params), (restored.bound_min, bank.bound_min),
                 (restored.bound_max, bank.bound_max), (restored_opt.exp_avg, opt.exp_avg),
                 (restored_opt.exp_avg_sq, opt.exp_avg_sq), (restored_opt.steps, opt.steps)]:
        assert torch.equal(a, b)
    train_steps(bank, opt, 2, seed=4)
    train_steps(restored, restored_opt, 2, seed=4)
    assert torch.equal(restored.params, bank.params)
    with pytest.raises(ValueError):
        InstanceFieldBank(FieldConfig(hidden_width=128), device="cpu").load_state_dict(saved["bank"])


# ---- sampling and rendering --------------------------------------------------------------------------
def test_sampler_follows_vmap_bands():
    g = torch.Generator().manual_seed(0)
    rays = RayBundle(torch.zeros(5, 3), torch.tensor([[0.0, 0.0, 1.0]]).expand(5, 3))
    depth = torch.tensor([2.0, 2.0, 0.0, 9.0, 0.5])
    own = torch.tensor([True, False, True, False, False])
    config = SamplerConfig(n_stratified=1, n_surface=9, far_m=8.0)
    samples = sample_along_rays(rays, depth, own, config, near=torch.tensor([0.0, 0.0, 0.0, 0.0, 1.0]), generator=g)
    d = samples.depths
    assert d.shape == (5, 10) and samples.positions.shape == (5, 10, 3)
    assert torch.all(d[:, 1:] >= d[:, :-1])
    assert 0.0 <= d[0, 0] <= 1.9 and torch.all((d[0, 1:] - 2.0).abs() <= 0.1)  # own: normal band
    assert torch.all((d[1, 1:] >= 1.9) & (d[1, 1:] <= 2.05))  # other surface: up to just behind it
    assert torch.all((d[2] >= 0) & (d[2] <= 8.0)) and torch.all((d[3] >= 0) & (d[3] <= 8.0))  # no depth / beyond far
    assert samples.occluded.tolist() == [False, False, False, False, True]  # surface before near
    assert torch.allclose(samples.positions[..., 2], d)


def test_render_occupancy_of_analytic_sphere_gives_its_depth():
    pose = look_at([1.5, 0.4, 0.3])
    rays = image_rays(pose, INTRINSICS)
    truth, hit = sphere_depth(rays)
    depths = torch.linspace(0.5, 2.5, 400).expand(*rays.shape, 400)
    occupancy = ((rays.at(depths)).norm(dim=-1) < RADIUS_M).float()
    rendered = render_occupancy(occupancy, torch.ones(*depths.shape, 3) * 0.5, depths)
    assert hit.float().mean() > 0.1
    assert (rendered.depth[hit] - truth[hit]).abs().max() < 0.01  # spacing 5 mm
    assert torch.allclose(rendered.occupancy, hit.float())
    assert torch.allclose(rendered.colour[hit], torch.full((int(hit.sum()), 3), 0.5))
    assert torch.allclose(rendered.weights.sum(-1), rendered.occupancy)
    # Soft occupancies: T_p = o_p prod_{q<p} (1 - o_q).
    o = torch.tensor([[0.2, 0.5, 1.0, 0.7]])
    r = render_occupancy(o, None, torch.tensor([[1.0, 2.0, 3.0, 4.0]]))
    assert torch.allclose(r.weights, torch.tensor([[0.2, 0.4, 0.4, 0.0]]), atol=1e-6)
    assert torch.allclose(r.depth, torch.tensor([0.2 + 0.8 + 1.2]))


def test_ray_aabb_slab_test():
    origins = torch.tensor([[-2.0, 0.5, 0.5], [-2.0, 3.0, 0.5], [0.5, 0.5, 0.5]])
    directions = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    t_near, t_far = ray_aabb(origins, directions, torch.zeros(3), torch.ones(3))
    assert torch.allclose(t_near[[0, 2]], torch.tensor([2.0, -0.5])) and torch.allclose(t_far[[0, 2]], torch.tensor([3.0, 0.5]))
    assert t_far[1] < t_near[1]  # miss


def test_composite_two_banks_analytic_spheres():
    near_sphere = AnalyticField([(0.0, 0.0, 0.0)], [RADIUS_M])
    far_spheres = AnalyticField([(-0.6, -0.3, 0.0), (0.0, 0.0, -0.25)], [0.35, 0.2])  # the second overlaps the first box
    pose = look_at([1.5, 0.0, 0.2])
    config = CompositeConfig(samples_per_box=128, rays_per_chunk=300)
    image = render_image([near_sphere, far_spheres], pose, INTRINSICS, config, labels=[torch.tensor([7]), torch.tensor([8, 9])])
    rays = image_rays(pose, INTRINSICS)
    d0, h0 = sphere_depth(rays)
    d1, h1 = sphere_depth(rays, (-0.6, -0.3, 0.0), 0.35)
    d2, h2 = sphere_depth(rays, (0.0, 0.0, -0.25), 0.2)
    big = torch.tensor(99.0)
    truth = torch.stack([torch.where(h, d, big) for d, h in [(d0, h0), (d1, h1), (d2, h2)]]).min(0)
    hit = truth.values < 99
    assert image.depth.shape == (36, 48) and image.colour.shape == (36, 48, 3) and image.instance.shape == (36, 48)
    assert h1.any() and (h2 & ~h0).any()
    assert (image.depth[hit] - truth.values[hit]).abs().max() < 0.01
    expected = torch.tensor([7, 8, 9])[truth.indices]
    assert torch.equal(image.instance[hit], expected[hit])
    assert torch.all(image.instance[~hit] == -1) and torch.all(image.occupancy[~hit] == 0)
    # Differentiable path and default labels (rows numbered across banks).
    flat = composite_instances([near_sphere, far_spheres], rays.flatten(), config, with_colour=False)
    assert flat.colour is None and set(flat.instance[hit.flatten()].tolist()) <= {0, 1, 2}


# ---- losses ------------------------------------------------------------------------------------------
def test_losses_follow_eq_8_to_11():
    occupancy = torch.tensor([[1.0, 0.5, 0.0], [0.2, 0.2, 0.2]])
    mask = torch.tensor([[1.0, 1.0, 0.0], [0.0, 0.0, 0.0]])
    # Mean over rays per instance, sum over instances.
    assert torch.isclose(occupancy_loss(occupancy, mask), torch.tensor(0.5 / 3 + 0.2))
    assert torch.isclose(masked_mean(torch.ones(2, 3), torch.zeros(2, 3)), torch.tensor(0.0))
    depth_gt = torch.tensor([[2.0, 0.0, 1.0], [1.0, 1.0, 1.0]])  # 0 = no reading
    rendered_depth = torch.tensor([[2.5, 7.0, 7.0], [9.0, 9.0, 9.0]])
    assert torch.isclose(depth_loss(rendered_depth, depth_gt, mask), torch.tensor(0.5))
    assert torch.isclose(depth_loss(rendered_depth, depth_gt, mask, variance=torch.full((2, 3), 0.25)),
                         torch.tensor(0.5 / (0.5 + 1e-4)))
    from mapping.model.render import RenderedRays

    rendered = RenderedRays(occupancy, rendered_depth, torch.zeros(2, 3, 3), torch.zeros(2, 3, 1), torch.zeros(2, 3))
    rgb = torch.full((2, 3, 3), 0.5)
    loss = data_loss(rendered, depth_gt, rgb, mask, weights=DataLossWeights(depth_uncertainty=False))
    assert torch.isclose(loss.colour, torch.tensor(0.5))
    assert torch.isclose(loss.total, 10 * loss.occupancy + 1 * loss.depth + 5 * loss.colour)


# ---- learning ----------------------------------------------------------------------------------------
def test_one_instance_learns_a_sphere_from_depth():
    """300 steps of 256 rays from 16 views (about 3 s on one core) -> held-out depth error < 2 cm."""
    g = torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    train_poses = [look_at([1.2 * math.cos(a), 1.2 * math.sin(a), z])
                   for z, phase in [(0.5, 0.0), (-0.4, 0.3)] for a in phase + torch.arange(8) * math.pi / 4]
    poses = torch.stack(train_poses)
    bank = InstanceFieldBank(FieldConfig(hidden_width=32), device="cpu")
    bank.add_instances(1, torch.full((1, 3), -0.4), torch.full((1, 3), 0.4), generator=g)
    opt = StackedAdam(bank, AdamConfig(lr=5e-3))
    n_rays, colour = 256, torch.tensor([0.8, 0.3, 0.2])
    for _ in range(300):
        view = torch.randint(len(poses), (1, n_rays), generator=g)  # (N=1, R) layout, as the mapper's
        u, v = torch.rand(1, n_rays, generator=g) * INTRINSICS.width, torch.rand(1, n_rays, generator=g) * INTRINSICS.height
        rays = camera_rays(poses[view], INTRINSICS, u, v)
        depth, own = sphere_depth(rays)
        depth = torch.where(own, depth, torch.full_like(depth, 3.0))  # a wall behind
        t_near, t_far = ray_aabb(rays.origins, rays.directions, bank.bound_min[:, None], bank.bound_max[:, None])
        samples = sample_along_rays(rays, depth, own, near=t_near.clamp_min(0.0), far=t_far, generator=g)
        occupancy, col = bank(samples.positions.reshape(1, -1, 3))
        rendered = render_occupancy(occupancy.reshape(samples.depths.shape), col.reshape(*samples.depths.shape, 3),
                                    samples.depths)
        loss = data_loss(rendered, depth, colour.expand(1, n_rays, 3), own, valid=(t_far > t_near) & ~samples.occluded)
        opt.zero_grad()
        loss.total.backward()
        opt.step()

    held_out = look_at([0.9, 0.8, 0.1])
    image = render_image([bank], held_out, INTRINSICS, CompositeConfig(samples_per_box=96))
    truth, hit = sphere_depth(image_rays(held_out, INTRINSICS))
    interior = hit.clone()  # drop silhouette pixels (a ray grazing the sphere)
    interior[1:-1, 1:-1] = hit[1:-1, 1:-1] & hit[:-2, 1:-1] & hit[2:, 1:-1] & hit[1:-1, :-2] & hit[1:-1, 2:]
    error = (image.depth - truth).abs()[interior]
    assert error.mean() < 0.02, f"mean held-out depth error {error.mean():.4f} m"
    assert (image.instance[interior] == 0).float().mean() > 0.95
    assert (image.colour[interior] - colour).abs().mean() < 0.1


def test_mapping_field_modules_import_no_env_packages():
    code = ("import sys, mapping.model.field, mapping.model.render, mapping.model.losses; "
            "bad = [m for m in ('pettingzoo', 'gymnasium', 'pyrender', 'openmulti_env') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_samples_are_in_depth_order_when_the_box_starts_inside_the_surface_band():
    from mapping.model.render import RayBundle, sample_along_rays

    rays = RayBundle(torch.zeros(64, 3), torch.tensor([[0.0, 0.0, 1.0]]).expand(64, 3).contiguous())
    depth = torch.full((64,), 2.0)
    near = torch.full((64,), 1.95)  # the box starts 5 cm before the surface; the band is +-10 cm
    samples = sample_along_rays(rays, depth, near=near, far=torch.full((64,), 3.0),
                                generator=torch.Generator().manual_seed(0))
    assert bool(torch.all(samples.depths[:, 1:] >= samples.depths[:, :-1]))


def test_depth_and_colour_losses_ignore_invalid_rays():
    from mapping.model.losses import data_loss
    from mapping.model.render import render_occupancy

    occ = torch.tensor([[0.0, 0.0, 0.9], [0.0, 0.0, 0.9]])
    depths = torch.tensor([[1.0, 1.5, 2.0], [1.0, 1.5, 2.0]])
    rendered = render_occupancy(occ, torch.full((2, 3, 3), 0.5), depths)
    depth, rgb, mask = torch.tensor([1.8, 50.0]), torch.tensor([[0.5] * 3, [0.0] * 3]), torch.ones(2)
    only_first = data_loss(rendered, depth, rgb, mask, torch.tensor([True, False]))
    first_ray = render_occupancy(occ[:1], torch.full((1, 3, 3), 0.5), depths[:1])
    alone = data_loss(first_ray, depth[:1], rgb[:1], mask[:1])
    assert torch.allclose(only_first.depth, alone.depth) and torch.allclose(only_first.colour, alone.colour)


def test_free_space_loss_counts_only_samples_in_front_of_an_observed_surface():
    from mapping.model.losses import free_space_loss

    occupancy = torch.tensor([[[0.5, 0.2, 1.0], [0.9, 0.9, 0.9]]])  # (N=1, R=2, S=3)
    depths = torch.tensor([[[0.5, 1.0, 2.0], [0.5, 1.0, 2.0]]])
    depth = torch.tensor([[2.0, 0.0]])  # ray 1 has no depth: nothing known in front of it
    loss = free_space_loss(occupancy, depths, depth, torch.ones(1, 2, dtype=torch.bool), margin_m=0.1)
    assert loss.item() == pytest.approx((0.5 + 0.2) / 2)  # the sample at 2.0 is on the surface band
    assert free_space_loss(occupancy, depths, depth, torch.zeros(1, 2, dtype=torch.bool), 0.1).item() == 0.0


def test_query_blocks_pad_little_and_give_every_point_its_instances_value():
    """Very unequal instances (a wall and a cup): blocks far smaller than the largest instance, and the same
    values as each instance evaluated alone."""
    from mapping.model.field import query_block

    counts = torch.tensor([3000, 40, 0, 700, 5])
    block = query_block(counts)
    padded = int((((counts + block - 1) // block) * block)[counts > 0].sum())
    assert block < 3000 and padded < 1.5 * int(counts.sum())  # one 3000-point block each: 3.2x the points
    assert query_block(torch.tensor([7, 7])) == 7 and query_block(torch.tensor([5000]), block_size=256) <= 256
    bank = make_bank(5)
    gen = torch.Generator().manual_seed(1)
    rows = torch.repeat_interleave(torch.arange(5), counts)
    rows = rows[torch.randperm(len(rows), generator=gen)]
    lo, hi = bank.bound_min[rows], bank.bound_max[rows]
    pts = lo + (hi - lo) * torch.rand(len(rows), 3, generator=gen)
    with torch.no_grad():  # the reading paths (column map, probes); under autograd one block as before
        packed = bank.query(pts, rows)
    trained = bank.query(pts, rows)
    torch.testing.assert_close(trained.occupancy.detach(), packed.occupancy, rtol=0, atol=1e-6)
    for i in (0, 1, 3, 4):
        alone = bank(pts[rows == i][None], rows=torch.tensor([i]))
        torch.testing.assert_close(packed.occupancy[rows == i], alone.occupancy[0].detach(), rtol=0, atol=1e-6)
        torch.testing.assert_close(packed.colour[rows == i], alone.colour[0].detach(), rtol=0, atol=1e-6)
