"""The geometric segmenter (planes + Euclidean clusters) on hand-made depth images."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mapping.data import Frame, Intrinsics
from mapping.perception.geometric_segmenter import (OBJECT_CAPTION, PLANE_CAPTION, GeometricSegmenter,
                                                    RANGE_AWARE, GeometricSegmenterConfig, ransac_plane,
                                                    instance_caption)

K = Intrinsics.from_fov(160, 120, 90.0)


def _looking_down(depth: np.ndarray) -> Frame:
    """A camera 2 m above the floor looking straight down (OpenCV axes: z down into the floor)."""
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[2, 3] = 2.0
    rgb = np.full((*depth.shape, 3), 128, np.uint8)
    return Frame(rgb, depth.astype(np.float32), pose, K, index=3)


def _two_boxes() -> tuple[Frame, np.ndarray, np.ndarray, np.ndarray]:
    """Floor at 2 m, a 40 cm box and a 30 cm box on it, 20 px apart; masks of floor and boxes."""
    depth = np.full((120, 160), 2.0)
    box_a = np.zeros(depth.shape, bool)
    box_a[30:80, 20:70] = True
    box_b = np.zeros(depth.shape, bool)
    box_b[40:90, 90:140] = True
    depth[box_a] = 1.6
    depth[box_b] = 1.7
    depth[:, :3] = 0.0  # a strip without depth readings
    return _looking_down(depth), box_a, box_b, ~(box_a | box_b) & (depth > 0)


def _dominant(labels: np.ndarray, region: np.ndarray) -> tuple[int, float]:
    ids, counts = np.unique(labels[region], return_counts=True)
    k = int(np.argmax(counts))
    return int(ids[k]), float(counts[k] / region.sum())


def test_two_boxes_on_a_plane_are_separated_from_each_other_and_the_floor():
    frame, box_a, box_b, floor = _two_boxes()
    seg = GeometricSegmenter().segment(frame)
    id_a, share_a = _dominant(seg.labels, box_a)
    id_b, share_b = _dominant(seg.labels, box_b)
    id_floor, share_floor = _dominant(seg.labels, floor)
    assert share_a > 0.8 and share_b > 0.8 and share_floor > 0.9
    assert len({id_a, id_b, id_floor}) == 3 and 0 not in (id_a, id_b, id_floor)
    # no segment holds much of two of them
    for sid in (id_a, id_b, id_floor):
        spread = [np.mean(seg.labels[r] == sid) for r in (box_a, box_b, floor)]
        assert sorted(spread)[-2] < 0.05
    assert seg.segment(id_floor).caption == PLANE_CAPTION
    assert np.all(seg.labels[frame.depth == 0] == 0)  # no depth, no mask
    assert {s.segment_id for s in seg.segments} == set(np.unique(seg.labels)) - {0}
    assert seg.frame_index == 3 and all(s.pixels >= 100 for s in seg.segments)


def test_a_clutter_cluster_is_an_object_and_small_specks_are_dropped():
    depth = np.full((120, 160), 2.0)
    depth[50:70, 60:80] = 1.5 - 0.002 * np.arange(20)[None, :]  # a slanted small thing: not a large plane
    depth[5:8, 5:8] = 1.0  # 9 pixels: below the minimum mask size
    seg = GeometricSegmenter().segment(_looking_down(depth))
    thing, share = _dominant(seg.labels, (depth < 1.9) & (depth > 1.1))
    floor, _ = _dominant(seg.labels, depth == 2.0)
    assert thing != 0 and share > 0.8 and seg.segment(thing).caption == OBJECT_CAPTION
    assert set(np.unique(seg.labels[5:8, 5:8])) <= {0, floor}  # the speck is no mask of its own


def test_a_frame_without_depth_has_no_masks_and_captions_are_numbered():
    seg = GeometricSegmenter().segment(_looking_down(np.zeros((120, 160))))
    assert seg.segments == [] and not seg.labels.any()
    assert instance_caption(PLANE_CAPTION, 3) == "planar surface 3"
    assert instance_caption(OBJECT_CAPTION, 7) == "object 7"


K_VGA = Intrinsics.from_fov(640, 480, 60.0)


def _far_wall_and_box(seed: int = 0) -> tuple[Frame, np.ndarray, np.ndarray]:
    """A camera facing a near plane (lower two thirds, 1.2 m) below a far wall (4.5 m) with a box face at
    3.5 m before it, at 640x480 with structured-light noise (1.5 mm x depth^2): the frame's median depth
    is near, so one threshold for the frame fits the near part only."""
    depth = np.full((480, 640), 4.5)
    depth[160:, :] = 1.2
    box = np.zeros(depth.shape, bool)
    box[40:120, 260:380] = True
    depth[box] = 3.5
    depth += np.random.default_rng(seed).normal(0.0, 0.0015 * depth**2)
    rgb = np.full((*depth.shape, 3), 128, np.uint8)
    far = np.zeros(depth.shape, bool)
    far[:160] = True
    return Frame(rgb, depth.astype(np.float32), np.eye(4), K_VGA, index=5), far & ~box, box


def test_a_far_noisy_wall_is_one_plane_and_a_box_before_it_its_own_segment():
    frame, wall, box = _far_wall_and_box()
    seg = GeometricSegmenter(RANGE_AWARE).segment(frame)
    wall_id, wall_share = _dominant(seg.labels, wall)
    box_id, box_share = _dominant(seg.labels, box)
    assert wall_id != 0 and wall_share > 0.95 and seg.segment(wall_id).caption == PLANE_CAPTION
    assert box_id not in (0, wall_id) and box_share > 0.8
    assert np.mean(seg.labels > 0) > 0.95


def test_one_threshold_for_the_whole_frame_loses_the_far_wall():
    # the default (fixed 2 cm planes, one DBSCAN radius for the frame)
    frame, wall, _ = _far_wall_and_box()
    assert np.mean(GeometricSegmenter().segment(frame).labels[wall] > 0) < 0.5


def test_an_unknown_clustering_is_refused_by_name():
    with pytest.raises(ValueError, match="unknown clustering 'kmeans'"):
        GeometricSegmenter(GeometricSegmenterConfig(clustering="kmeans"))


def test_a_frame_gets_the_same_masks_every_time_and_the_seed_moves_them():
    # RANSAC draws from a generator of (seed, frame index), never from a global one
    frame, _, _ = _far_wall_and_box(seed=3)
    first = GeometricSegmenter().segment(frame)
    np.random.seed(123)  # global generators do not matter
    again = GeometricSegmenter().segment(frame)
    assert np.array_equal(first.labels, again.labels)
    assert [s.caption for s in first.segments] == [s.caption for s in again.segments]
    for config in (RANGE_AWARE, GeometricSegmenterConfig(seed=1)):
        assert np.array_equal(GeometricSegmenter(config).segment(frame).labels,
                              GeometricSegmenter(config).segment(frame).labels)
    other_seed = GeometricSegmenter(replace(RANGE_AWARE, seed=1)).segment(frame)
    assert not np.array_equal(GeometricSegmenter(RANGE_AWARE).segment(frame).labels, other_seed.labels)


def test_ransac_finds_the_plane_with_most_points_and_survives_degenerate_points():
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(0, 2, (600, 2)), rng.normal(0, 0.003, 600)]
    wall = np.c_[rng.uniform(0, 2, 300), np.full(300, 2.0), rng.uniform(0, 1, 300)]
    points = np.vstack([floor, wall])
    inliers = ransac_plane(points, np.full(len(points), 0.02), 200, np.random.default_rng(1))
    assert np.mean(inliers < 600) > 0.95 and np.sum(inliers < 600) > 0.95 * 600  # the floor, not the wall
    same = np.zeros((50, 3))  # every triple degenerate: no plane, no crash
    assert len(ransac_plane(same, np.full(50, 0.02), 20, np.random.default_rng(0))) == 0


def test_a_trail_of_stray_points_does_not_join_two_objects():
    # two small things on the floor joined by a one-cell-wide line at their height: with the core rule the
    # line's points have two linked neighbours, not the core's six, so it bridges nothing (as in DBSCAN)
    depth = np.full((120, 160), 2.0)
    depth[40:70, 30:60] = 1.5
    depth[40:70, 100:130] = 1.5
    depth[54:56, 60:100] = 1.5  # 2 pixels = one cell of the stride-2 grid
    # (as planes, coplanar pieces are joined on purpose; uncut, so that only the core rule separates them)
    clusters_only = replace(RANGE_AWARE, max_planes=0, max_object_extent_m=None)
    joined = GeometricSegmenter(clusters_only).segment(_looking_down(depth))
    assert joined.labels[55, 45] != 0 and joined.labels[55, 45] == joined.labels[55, 115]  # without it: one piece
    seg = GeometricSegmenter(replace(clusters_only, cluster_core_neighbours=6)).segment(_looking_down(depth))
    left_box, right_box = np.zeros(depth.shape, bool), np.zeros(depth.shape, bool)
    left_box[40:70, 30:60] = right_box[40:70, 100:130] = True
    left, share_left = _dominant(seg.labels, left_box)
    right, share_right = _dominant(seg.labels, right_box)
    assert 0 not in (left, right) and left != right and share_left > 0.9 and share_right > 0.9
    assert seg.segment(left).caption == seg.segment(right).caption == OBJECT_CAPTION


def test_pixels_beyond_max_depth_get_no_mask_and_the_rest_is_segmented_as_before():
    frame, wall, box = _far_wall_and_box()
    capped = GeometricSegmenter(replace(RANGE_AWARE, max_depth_m=4.0)).segment(frame)
    assert not capped.labels[wall].any()  # the wall at 4.5 m
    box_id, share = _dominant(capped.labels, box)
    assert box_id != 0 and share > 0.8
    assert np.mean(capped.labels[160:] > 0) > 0.95  # the near plane


def test_ransac_on_too_few_points_finds_nothing():
    assert len(ransac_plane(np.zeros((2, 3)), np.full(2, 0.02), 10, np.random.default_rng(0))) == 0


def test_an_object_cluster_wider_than_the_limit_is_cut_on_a_world_lattice_and_a_small_one_is_not():
    from mapping.perception.geometric_segmenter import lattice_parts

    depth = np.full((120, 160), 2.0)
    depth[40:80, 10:150] = 1.45 + 0.06 * np.sin(np.arange(140) / 5.0)[None, :]  # clutter about 2.6 m long: no plane
    depth[95:110, 70:90] = 1.6 - 0.002 * np.arange(20)[None, :]  # a small thing, under a metre
    frame = _looking_down(depth)
    whole = GeometricSegmenter(GeometricSegmenterConfig(max_object_extent_m=None)).segment(frame)
    cut = GeometricSegmenter().segment(frame)  # the default cuts at 1 m
    counter = np.zeros(depth.shape, bool)
    counter[40:80, 10:150] = True
    small = np.zeros(depth.shape, bool)
    small[95:110, 70:90] = True
    assert len(set(np.unique(whole.labels[counter])) - {0}) == 1
    parts = set(np.unique(cut.labels[counter])) - {0}
    assert len(parts) >= 3  # about 2.6 m on a 1 m lattice
    points = frame.backproject(mask=np.ones(depth.shape, bool))
    for part in parts:  # each part within one lattice cell: at most 1 m wide
        xyz = points[(cut.labels[depth > 0] == part)]
        assert np.all(np.ptp(xyz, axis=0) <= 1.0 + 1e-6)
    thing, share = _dominant(cut.labels, small)
    assert share > 0.8 and cut.segment(thing).caption == OBJECT_CAPTION  # under a metre: whole
    again = GeometricSegmenter().segment(frame)
    assert np.array_equal(again.labels, cut.labels)
    tiny = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    assert [p.tolist() for p in lattice_parts(tiny, np.arange(2), 1.0, 1)] == [[0, 1]]
    with pytest.raises(ValueError, match="max_object_extent_m"):
        GeometricSegmenterConfig(max_object_extent_m=0.0)
