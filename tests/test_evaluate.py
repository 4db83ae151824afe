"""Meshing of instance fields and the vMAP/MACIM geometric metrics, on analytic shapes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
import trimesh

from mapping.evaluate import (
    COMPLETION_RATIO_THRESHOLD_M,
    INSTANCE_ID_PROPERTY,
    accuracy_completion,
    evaluate_mesh,
    evaluate_per_instance,
    export_scene_mesh,
    extract_instance_mesh,
    grid_for_bound,
    load_scene_mesh,
    merge_instance_meshes,
    sample_points,
)

VOXEL_M = 0.01
SHARPNESS_M = 0.005
"""Width of the analytic sigmoid fields: narrower than a voxel, like a trained vMAP field (10x logits)."""
SAMPLING_FLOOR_CM = 0.3
"""Mean nearest-neighbour distance between two independent 200k samples of 1 m^2 is about 0.11 cm."""
SHIFT_TOL_CM = 0.05
"""Nearest sample on a parallel plane is off the normal by about 1 mm: sqrt(3^2 + 0.1^2) - 3 < 0.01 cm."""


def sphere_occupancy(radius_m: float, center=(0.0, 0.0, 0.0)):
    center_t = torch.tensor(center, dtype=torch.float32)
    return lambda p: torch.sigmoid((radius_m - (p - center_t).norm(dim=-1)) / SHARPNESS_M)


def square(
    side_m: float = 1.0, z_m: float = 0.0, x0_m: float = 0.0, width_m: float | None = None
) -> trimesh.Trimesh:
    """A flat rectangle in the plane z = z_m: x in [x0, x0 + width] (width defaults to side), y in [0, side]."""
    width_m = side_m if width_m is None else width_m
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64) * [width_m, side_m, 0.0]
    v += [x0_m, 0.0, z_m]
    return trimesh.Trimesh(vertices=v, faces=[[0, 1, 2], [0, 2, 3]], process=False)


# ---------------------------------------------------------------- meshing


def test_sphere_mesh_is_on_the_radius_and_closed():
    radius = 0.2
    mesh = extract_instance_mesh(sphere_occupancy(radius), [-0.25] * 3, [0.25] * 3, voxel_size_m=VOXEL_M)
    assert mesh is not None
    radii = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(radii - radius).max() < VOXEL_M
    assert mesh.is_watertight
    assert mesh.euler_number == 2
    assert mesh.volume > 0  # faces wound outward
    assert mesh.volume == pytest.approx(4.0 / 3.0 * math.pi * radius**3, rel=0.02)


def test_color_fn_gives_uint8_rgba_vertex_colours():
    mesh = extract_instance_mesh(
        sphere_occupancy(0.1), [-0.15] * 3, [0.15] * 3, voxel_size_m=VOXEL_M,
        color_fn=lambda p: torch.tensor([1.0, 0.5, 0.0]).expand(len(p), 3),
    )
    colors = mesh.visual.vertex_colors
    assert colors.dtype == np.uint8 and colors.shape == (len(mesh.vertices), 4)
    assert np.all(colors == [255, 128, 0, 255])


def test_surface_cut_by_the_box_is_closed_by_the_padding():
    # A box-shaped solid that sticks out of the bound through the x = -0.2 face.
    def occupancy(p):
        return ((p[:, 0] < 0.1) & (p[:, 1].abs() < 0.1) & (p[:, 2].abs() < 0.1)).float()

    mesh = extract_instance_mesh(occupancy, [-0.2] * 3, [0.2] * 3, voxel_size_m=VOXEL_M)
    assert mesh.is_watertight and mesh.volume > 0
    # The cap sits half a voxel outside the bound, between the last sample and the zero padding.
    assert mesh.bounds[0, 0] == pytest.approx(-0.2 - VOXEL_M / 2, abs=1e-6)


def test_no_crossing_gives_none_and_full_box_gives_closed_box():
    assert extract_instance_mesh(lambda p: torch.zeros(len(p)), [0.0] * 3, [1.0] * 3, voxel_size_m=0.1) is None
    assert extract_instance_mesh(lambda p: torch.full((len(p),), 0.4), [0.0] * 3, [1.0] * 3, voxel_size_m=0.1) is None
    full = extract_instance_mesh(lambda p: torch.ones(len(p), 1), [0.0] * 3, [1.0] * 3, voxel_size_m=0.1)
    assert full.is_watertight
    np.testing.assert_allclose(full.bounds, [[-0.05] * 3, [1.05] * 3], atol=1e-6)


def test_max_resolution_caps_the_grid_and_grows_the_voxel():
    origin, voxel, shape = grid_for_bound(
        [-1.0, -1.0, -0.5], [1.0, 1.0, 0.5], voxel_size_m=0.01, max_resolution=64
    )
    assert shape == (64, 64, 33)
    assert voxel == pytest.approx(2.0 / 63)
    np.testing.assert_allclose(origin, [-1.0, -1.0, -0.5])
    assert grid_for_bound([0.0] * 3, [0.5] * 3, 0.01, 256)[2] == (51, 51, 51)

    seen = []

    def occupancy(p):
        seen.append(len(p))
        return sphere_occupancy(0.5)(p)

    mesh = extract_instance_mesh(
        occupancy, [-1.0] * 3, [1.0] * 3, voxel_size_m=0.01, max_resolution=32, batch_points=5000
    )
    assert sum(seen) == 32**3 and max(seen) <= 5000
    assert mesh is not None


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="non-finite"):
        extract_instance_mesh(lambda p: torch.full((len(p),), float("nan")), [0.0] * 3, [1.0] * 3, voxel_size_m=0.1)
    with pytest.raises(ValueError, match="exceed"):
        extract_instance_mesh(sphere_occupancy(0.1), [0.0] * 3, [1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="shape"):
        extract_instance_mesh(lambda p: torch.zeros(len(p), 2), [0.0] * 3, [1.0] * 3, voxel_size_m=0.1)


def test_merge_and_ply_round_trip_keep_instance_ids(tmp_path):
    a = extract_instance_mesh(sphere_occupancy(0.1), [-0.15] * 3, [0.15] * 3, voxel_size_m=VOXEL_M,
                              color_fn=lambda p: torch.full((len(p), 3), 0.2))
    b = extract_instance_mesh(
        sphere_occupancy(0.1, (0.5, 0, 0)), [0.35, -0.15, -0.15], [0.65, 0.15, 0.15], voxel_size_m=VOXEL_M
    )
    scene, ids = merge_instance_meshes({7: b, 3: a, 9: None})
    assert ids.dtype == np.int32 and ids.shape == (len(a.vertices) + len(b.vertices),)
    assert np.all(ids[: len(a.vertices)] == 3) and np.all(ids[len(a.vertices):] == 7)  # ascending ids
    assert len(scene.faces) == len(a.faces) + len(b.faces)
    np.testing.assert_array_equal(scene.vertex_attributes[INSTANCE_ID_PROPERTY], ids)
    np.testing.assert_allclose(scene.vertices[ids == 7].mean(axis=0), [0.5, 0, 0], atol=1e-3)

    path = export_scene_mesh(tmp_path / "sub" / "scene.ply", scene, ids)
    assert [p.name for p in path.parent.iterdir()] == ["scene.ply"]  # no temp file left behind
    loaded, loaded_ids = load_scene_mesh(path)
    np.testing.assert_array_equal(loaded_ids, ids)
    np.testing.assert_allclose(loaded.vertices, scene.vertices, atol=1e-6)  # float32 in the file
    np.testing.assert_array_equal(loaded.faces, scene.faces)
    np.testing.assert_array_equal(loaded.visual.vertex_colors, scene.visual.vertex_colors)
    assert np.all(loaded.visual.vertex_colors[ids == 3, :3] == 51)  # colour from color_fn kept

    empty_scene, empty_ids = merge_instance_meshes({1: None})
    assert len(empty_scene.vertices) == 0 and empty_ids.shape == (0,)


# ---------------------------------------------------------------- metrics


def test_mesh_against_itself_is_at_the_sampling_floor():
    plane = square(1.0)
    metrics = evaluate_mesh(plane, plane, count=200_000, seed=0)
    assert metrics.acc_cm < SAMPLING_FLOOR_CM and metrics.comp_cm < SAMPLING_FLOOR_CM
    assert metrics.comp_ratio == 100.0
    assert metrics.n_rec_points == metrics.n_gt_points == 200_000 and not metrics.empty


@pytest.mark.parametrize("shift_cm, ratio", [(3.0, 100.0), (8.0, 0.0)])
def test_plane_shifted_along_its_normal(shift_cm, ratio):
    metrics = evaluate_mesh(square(1.0, z_m=shift_cm / 100.0), square(1.0), count=200_000, seed=1)
    assert metrics.acc_cm == pytest.approx(shift_cm, abs=SHIFT_TOL_CM)
    assert metrics.comp_cm == pytest.approx(shift_cm, abs=SHIFT_TOL_CM)
    assert metrics.comp_ratio == ratio


def test_half_reconstruction_completes_half_plus_the_threshold_strip():
    side = 2.0
    gt_points = sample_points(square(side), 100_000, seed=0)
    rec_points = sample_points(square(side, width_m=side / 2), 50_000, seed=1)  # x in [0, 1] of [0, 2]
    metrics = accuracy_completion(rec_points, gt_points)
    # Completed: the covered half plus a strip of the threshold's width beyond its edge.
    expected = 100.0 * (side / 2 + COMPLETION_RATIO_THRESHOLD_M) / side
    assert metrics.comp_ratio == pytest.approx(expected, abs=0.5)
    # Sampling floor at 100k points on 4 m^2: about 0.5 / sqrt(25k per m^2) = 0.32 cm.
    assert metrics.acc_cm < 0.5
    # Mean distance to the covered half: (1/2) * mean over [0, 1] of the gap = 25 cm.
    assert metrics.comp_cm == pytest.approx(25.0, abs=0.5)


def test_empty_reconstruction_gives_the_documented_result():
    for rec in (None, trimesh.Trimesh()):
        metrics = evaluate_mesh(rec, square(1.0), count=1000)
        assert metrics.empty
        assert metrics.acc_cm == math.inf and metrics.comp_cm == math.inf and metrics.comp_ratio == 0.0
        assert metrics.n_rec_points == 0 and metrics.n_gt_points == 1000
        d = metrics.as_dict()
        assert d["acc_cm"] is None and d["comp_cm"] is None and d["empty"] is True
        json.dumps(d, allow_nan=False)  # strict JSON
    with pytest.raises(ValueError, match="gt_mesh"):
        evaluate_mesh(square(1.0), None)


def test_bad_point_sets_raise_naming_the_set():
    good = np.zeros((4, 3))
    bad = good.copy()
    bad[2, 1] = np.nan
    with pytest.raises(ValueError, match="rec_points has 1 of 4 points with non-finite"):
        accuracy_completion(bad, good)
    bad[2, 1] = np.inf
    with pytest.raises(ValueError, match="gt_points has 1 of 4"):
        accuracy_completion(good, bad)
    with pytest.raises(ValueError, match="gt_points is empty"):
        accuracy_completion(good, np.zeros((0, 3)))
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        accuracy_completion(np.zeros((4, 2)), good)


def test_per_instance_metrics_and_as_dict():
    gt = {1: square(0.5), 2: square(0.5, x0_m=2.0)}
    rec = {1: square(0.5, z_m=0.03), 5: square(0.5)}  # 2 missing, 5 not in the ground truth
    metrics = evaluate_per_instance(rec, gt, count_per_instance=20_000, seed=0)
    assert list(metrics) == [1, 2]
    assert metrics[1].acc_cm == pytest.approx(3.0, abs=SHIFT_TOL_CM) and metrics[1].comp_ratio == 100.0
    assert metrics[2].empty and metrics[2].n_gt_points == 20_000
    d = metrics[1].as_dict()
    assert set(d) == {
        "acc_cm", "comp_cm", "comp_ratio", "n_rec_points", "n_gt_points", "ratio_threshold_m", "empty"
    }
    assert d["acc_cm"] == round(metrics[1].acc_cm, 4)
    json.dumps(d, allow_nan=False)


def test_surface_classes_split_right_invented_and_missed_by_the_completion_threshold():
    from mapping.evaluate.geometry import surface_classes

    gt = square(2.0)  # x, y in [0, 2] at z = 0
    half = square(2.0, width_m=1.0)  # the map has half the floor (x <= 1) ...
    floater = square(0.5, z_m=0.5)  # ... and a slab half a metre above it
    rec = trimesh.util.concatenate([half, floater])
    classes = surface_classes(rec, gt, count=20_000)
    assert np.allclose(classes.right[:, 2], 0.0) and (classes.right[:, 0] <= 1.0 + 1e-6).all()
    assert np.allclose(classes.invented[:, 2], 0.5)
    assert (classes.missed[:, 0] > 1.0 + COMPLETION_RATIO_THRESHOLD_M - 0.01).all()  # sampling: about 1 cm
    # by area: the slab is 0.25 of the map's 2.25 m^2, the missed strip about 1.9 of 4 m^2 of ground truth
    assert len(classes.invented) / 20_000 == pytest.approx(0.25 / 2.25, abs=0.02)
    assert len(classes.missed) / 20_000 == pytest.approx(0.475, abs=0.02)
    empty = surface_classes(None, gt, count=1000)
    assert len(empty.right) == len(empty.invented) == 0 and len(empty.missed) == 1000


def test_the_top_down_picture_draws_every_agent_even_without_a_mesh(tmp_path):
    from mapping.pipeline.plots import save_reconstruction_views

    gt = trimesh.util.concatenate([square(2.0), square(2.0, z_m=1.0)])  # a floor and a "ceiling"
    path = save_reconstruction_views(tmp_path / "top.png", gt, [square(2.0, width_m=1.0), None], "TSDF reference")
    assert path.stat().st_size > 10_000


def _reference_visibility(caster, viewpoints, points, normals, max_range_m):
    """The visibility test written point by point (what ``visibility_matrix`` must equal)."""
    from mapping.evaluate.visibility import OCCLUSION_SLACK_M, SURFACE_OFFSET_M

    lifted = points + SURFACE_OFFSET_M * normals
    out = np.zeros((len(viewpoints), len(points)), bool)
    for i, eye in enumerate(viewpoints):
        to_pt = lifted - eye
        dist = np.linalg.norm(to_pt, axis=1)
        ok = ((normals * to_pt).sum(axis=1) < 0) & (dist < max_range_m) & (dist > 1e-6)
        idx = np.flatnonzero(ok)
        t, _ = caster.cast(eye, to_pt[idx] / dist[idx, None])
        out[i, idx[t >= dist[idx] - OCCLUSION_SLACK_M]] = True
    return out


def test_visibility_matrix_equals_the_point_by_point_test_in_blocks_and_with_stop_when_seen():
    from mapping.evaluate.raycast import MeshRaycaster
    from mapping.evaluate.visibility import visibility_matrix

    boxes = [trimesh.creation.box(extents=e, transform=trimesh.transformations.translation_matrix(c))
             for e, c in [((4, 4, 2.5), (0, 0, 1.25)), ((0.6, 0.6, 0.8), (0.5, -0.4, 0.4)),
                          ((0.3, 1.2, 1.5), (-1.0, 0.8, 0.75))]]
    scene = trimesh.util.concatenate(boxes).subdivide().subdivide()
    rng = np.random.default_rng(3)
    points, face = trimesh.sample.sample_surface(scene, 3000, seed=1)
    normals = scene.face_normals[face]
    normals[::2] *= -1.0  # both sides of every wall
    viewpoints = rng.uniform([-1.9, -1.9, 0.2], [1.9, 1.9, 2.3], (23, 3))
    caster = MeshRaycaster(scene)
    for max_range in (8.0, 2.0):  # 2 m: the range test decides for many points
        expected = _reference_visibility(caster, viewpoints, points, normals, max_range)
        assert 0 < expected.sum() < expected.size
        for block in (1, 5, 64):
            full = visibility_matrix(caster, viewpoints, points, normals, max_range, block=block)
            np.testing.assert_array_equal(full, expected)
            first = visibility_matrix(caster, viewpoints, points, normals, max_range, stop_when_seen=True, block=block)
            np.testing.assert_array_equal(first.any(axis=0), expected.any(axis=0))
            assert first.sum(axis=0).max() == 1  # only the first viewpoint that saw a point
            seen = np.flatnonzero(first.any(axis=0))
            np.testing.assert_array_equal(first[:, seen].argmax(axis=0), expected[:, seen].argmax(axis=0))


def test_face_group_keys_number_groups_as_a_row_sort_does():
    from mapping.evaluate.visibility import group_keys

    rng = np.random.default_rng(0)
    cells = rng.integers(-40, 40, (5000, 3))
    side = rng.integers(0, 6, 5000)
    _, expected = np.unique(np.concatenate([cells, side[:, None]], axis=1), axis=0, return_inverse=True)
    _, got = np.unique(group_keys(cells, side), return_inverse=True)
    np.testing.assert_array_equal(got.reshape(-1), expected.reshape(-1))


def test_a_reference_sampled_once_scores_every_map_as_sampling_it_each_time():
    from mapping.evaluate import SampledSurface, evaluate_mesh

    gt = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    reference = SampledSurface.of(gt, count=5000, seed=4)
    for rec in (trimesh.creation.box(extents=(2.0, 1.0, 0.9)), trimesh.creation.icosphere(radius=0.6)):
        assert evaluate_mesh(rec, gt, count=5000, seed=4, reference=reference) == evaluate_mesh(rec, gt, count=5000, seed=4)
    with pytest.raises(ValueError, match="seed=4"):
        evaluate_mesh(rec, gt, count=5000, seed=5, reference=reference)
