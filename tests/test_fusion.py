"""Cross-frame fusion (coarse clustering + fine merge) and the confidence of eq. 1-2, on hand-made scenes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mapping.alignment.confidence import frame_confidence, instance_confidence, label_confidences
from mapping.data.frame import Frame, Intrinsics
from mapping.fusion import CoarseConfig, FineConfig, FusionConfig, edge_scores, fine_merge, fuse_frames, observe_masks
from mapping.fusion.merge import voxel_downsample
from mapping.perception import FrameSegmentation, Segment, shared_text_encoder


@pytest.fixture(scope="session")
def encoder():
    return shared_text_encoder()


# ----------------------------------------------------------------------------------------------
# A hand-made world: axis-aligned boxes, depth and instance images ray-cast analytically.

def look_at(eye, target) -> np.ndarray:
    """(4, 4) camera-to-world, OpenCV axes (x right, y down, z forward), world z up."""
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([r, np.cross(f, r), f], axis=1)
    pose[:3, 3] = eye
    return pose


def render_boxes(boxes, colours, pose, intr: Intrinsics, index: int) -> Frame:
    """Ray-cast boxes (k, 6) = (lo, hi) to a Frame; instance id of box k is k + 1."""
    v, u = np.mgrid[0:intr.height, 0:intr.width]
    dirs = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones(u.shape)], -1) @ pose[:3, :3].T
    inv = 1.0 / np.where(dirs == 0, 1e-12, dirs)
    depth, inst = np.full(u.shape, np.inf), np.zeros(u.shape, np.int32)
    for k, box in enumerate(np.asarray(boxes, float)):
        t0, t1 = (box[:3] - pose[:3, 3]) * inv, (box[3:] - pose[:3, 3]) * inv
        near, far = np.minimum(t0, t1).max(-1), np.maximum(t0, t1).min(-1)
        hit = (near <= far) & (near > 0) & (near < depth)
        depth[hit], inst[hit] = near[hit], k + 1
    rgb = np.zeros(u.shape + (3,), np.uint8)
    for k, c in enumerate(colours):
        rgb[inst == k + 1] = c
    depth = np.where(np.isfinite(depth), depth, 0).astype(np.float32)
    return Frame(rgb, depth, pose, intr, inst, index=index, timestamp=index)


def segment_frames(frames, captions, encoder, caption_of=None):
    """One segment per ground-truth id, captioned by ``captions[id]`` (or ``caption_of(frame_pos, id)``)."""
    segs = []
    for pos, f in enumerate(frames):
        ids, counts = np.unique(f.instance, return_counts=True)
        texts = [caption_of(pos, int(i)) if caption_of else captions[int(i)] for i in ids if i > 0]
        feats = encoder.encode(texts)
        segs.append(FrameSegmentation(f.index, f.instance.copy(), [
            Segment(int(i), t, int(c), feat, None, (int(i),))
            for (i, c), t, feat in zip([(i, c) for i, c in zip(ids, counts) if i > 0], texts, feats)]))
    return segs


INTR = Intrinsics.from_fov(160, 120, 70.0)
CHAIR = [-0.3, -0.3, 0.0, 0.3, 0.3, 0.8]
TABLE = [0.9, -0.4, 0.0, 1.7, 0.4, 0.7]


def orbit(boxes, colours, n=8, radius=3.0, centre=(0.7, 0.0, 0.4)):
    """n frames from an arc of cameras around ``centre``."""
    frames = []
    for k, a in enumerate(np.linspace(-1.0, 1.0, n)):
        eye = np.array(centre) + [radius * np.sin(a), -radius * np.cos(a), 0.9]
        frames.append(render_boxes(boxes, colours, look_at(eye, centre), INTR, 10 + k))
    return frames


@pytest.fixture(scope="module")
def two_objects(encoder):
    frames = orbit([CHAIR, TABLE], [(200, 40, 40), (40, 60, 200)])
    return frames, segment_frames(frames, {1: "a red chair", 2: "a blue table"}, encoder)


# ----------------------------------------------------------------------------------------------
# Confidence, eq. 1-2

def test_frame_confidence_empty_central_and_border():
    mask = np.zeros((100, 200), bool)
    assert frame_confidence(mask) == 0.0
    mask[40:60, 80:120] = True  # well inside the central region
    assert frame_confidence(mask) == 1.0
    mask[:] = False
    mask[0:10, 0:30] = True  # touches the border band: area ratio
    assert frame_confidence(mask) == pytest.approx(300 / 20000)
    mask[:] = False
    mask[10:90, 20:180] = True  # exactly the central region (10 % border) counts as inside
    assert frame_confidence(mask) == 1.0
    assert frame_confidence(mask, border_margin=0.2) == pytest.approx(80 * 160 / 20000)


def test_frame_confidence_rejects_bad_input():
    with pytest.raises(ValueError, match="border_margin"):
        frame_confidence(np.ones((4, 4), bool), border_margin=0.5)
    with pytest.raises(ValueError, match="mask"):
        frame_confidence(np.ones(4, bool))


def test_label_confidences_agree_with_frame_confidence():
    labels = np.zeros((60, 80), np.int32)
    labels[20:30, 30:50] = 1  # central
    labels[0:5, :] = 2  # top border
    labels[50:60, 70:80] = 5  # corner
    got = label_confidences(labels)
    assert set(got) == {1, 2, 5}
    for i, c in got.items():
        assert c == pytest.approx(frame_confidence(labels == i))


def test_instance_confidence_is_mean_over_all_frames():
    assert instance_confidence([1.0, 0.5], n_frames=4) == pytest.approx(0.375)
    assert instance_confidence([], n_frames=3) == 0.0
    with pytest.raises(ValueError, match="frames"):
        instance_confidence([1.0, 1.0], n_frames=1)
    with pytest.raises(ValueError, match="n_frames"):
        instance_confidence([], n_frames=0)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        instance_confidence([1.5], n_frames=2)


# ----------------------------------------------------------------------------------------------
# Geometry helpers

def test_voxel_downsample_averages_per_voxel_and_keeps_groups_apart():
    pts = np.array([[0.001, 0.001, 0.001], [0.003, 0.005, 0.007], [0.5, 0.5, 0.5]])
    out = voxel_downsample(pts, 0.01)
    assert out.shape == (2, 3)
    assert np.allclose(out[0], [0.002, 0.003, 0.004])
    out, groups = voxel_downsample(pts, 0.01, groups=np.array([1, 0, 0]))
    assert len(out) == 3 and groups.tolist() == [0, 0, 1]
    with pytest.raises(ValueError, match="voxel"):
        voxel_downsample(pts, 0.0)


# ----------------------------------------------------------------------------------------------
# Fusion on the hand-made scene

def test_one_object_in_many_frames_fuses_into_one_instance(encoder):
    frames = orbit([CHAIR], [(200, 40, 40)], n=10)
    segs = segment_frames(frames, {1: "a red chair"}, encoder)
    result = fuse_frames(frames, segs)
    assert len(result.instances) == 1
    inst = result.instances[1]
    assert len(inst.observations) == 10 and inst.caption == "a red chair"
    assert inst.source_ids == (1,)
    assert np.allclose(inst.colour, np.array([200, 40, 40]) / 255)
    # the points lie on the box surface (within half a voxel)
    lo, hi = np.array(CHAIR[:3]), np.array(CHAIR[3:])
    assert np.all(inst.points >= lo - 0.006) and np.all(inst.points <= hi + 0.006)
    assert np.isclose(np.linalg.norm(inst.caption_feature), 1.0)
    assert 0.0 < inst.confidence <= 1.0


def test_two_objects_stay_apart_and_label_image_gives_local_ids(two_objects):
    frames, segs = two_objects
    result = fuse_frames(frames, segs)
    assert sorted(result.instances) == [1, 2]
    by_source = {inst.source_ids[0]: lid for lid, inst in result.instances.items()}
    assert set(by_source) == {1, 2}
    assert result.instances[by_source[1]].caption == "a red chair"
    assert result.instances[by_source[2]].caption == "a blue table"
    for f, s in zip(frames, segs):
        local = result.label_image(s)
        for gt, lid in by_source.items():
            assert np.all(local[f.instance == gt] == lid)
        assert np.all(local[f.instance == 0] == 0)


def test_confidence_of_fused_instance_follows_eq_1_2(two_objects):
    frames, segs = two_objects
    result = fuse_frames(frames, segs)
    for lid, inst in result.instances.items():
        gt = inst.source_ids[0]
        expected = np.mean([frame_confidence(f.instance == gt) for f in frames])
        assert inst.confidence == pytest.approx(expected)


def test_connected_components_option_agrees_on_a_clean_scene(two_objects):
    frames, segs = two_objects
    result = fuse_frames(frames, segs, FusionConfig(coarse=CoarseConfig(communities="components")))
    assert len(result.instances) == 2


def test_fusion_is_deterministic(two_objects):
    frames, segs = two_objects
    a, b = fuse_frames(frames, segs), fuse_frames(frames, segs)
    assert a.assignment == b.assignment
    for lid in a.instances:
        assert np.array_equal(a.instances[lid].points, b.instances[lid].points)


def test_point_cap_coarsens_the_voxel_and_keeps_the_extent(two_objects):
    frames, segs = two_objects
    capped = fuse_frames(frames, segs, FusionConfig(max_points=50))
    full = fuse_frames(frames, segs)
    for lid, inst in capped.instances.items():
        assert 0 < len(inst.points) <= 50
        lo, hi = full.instances[lid].points.min(axis=0), full.instances[lid].points.max(axis=0)
        assert np.all(inst.points >= lo - 1e-9) and np.all(inst.points <= hi + 1e-9)
        spread = np.ptp(inst.points, axis=0)  # still spans the object, not a clump of it
        assert np.all(spread >= 0.5 * np.ptp(full.instances[lid].points, axis=0) - 0.02)


def test_absent_visual_feature_rescales_the_threshold(two_objects):
    frames, segs = two_objects
    masks = observe_masks(frames, segs)
    assert masks.visual_features is None
    pairs_text, scores_text = edge_scores(masks, CoarseConfig())
    # identical visual features everywhere add exactly w_visual to every score
    with_vis = [FrameSegmentation(s.frame_index, s.labels, [replace(g, visual_feature=np.array([1.0, 0.0, 0.0]))
                                                            for g in s.segments]) for s in segs]
    masks_vis = observe_masks(frames, with_vis)
    pairs_vis, scores_vis = edge_scores(masks_vis, CoarseConfig())
    common = {tuple(p): s for p, s in zip(pairs_text.tolist(), scores_text)}
    matched = [(common[tuple(p)], s) for p, s in zip(pairs_vis.tolist(), scores_vis) if tuple(p) in common]
    assert matched
    assert all(sv == pytest.approx(st + 0.30) for st, sv in matched)
    # a pair without visual features needs 1.0 * 1.3 / 1.6 instead of 1.0
    assert scores_text.min() >= 1.3 / 1.6 - 1e-9


def test_fine_merge_joins_two_clusters_of_one_object_with_slightly_different_captions(encoder):
    frames = orbit([CHAIR], [(200, 40, 40)], n=8)
    segs = segment_frames(frames, {}, encoder,
                          caption_of=lambda pos, i: "a wooden chair" if pos % 2 else "a brown wooden chair")
    masks = observe_masks(frames, segs)
    halves = [[m for m in range(len(masks)) if masks.frame_pos[m] % 2 == k] for k in (0, 1)]
    assert fine_merge(masks, halves) == [list(range(len(masks)))]
    # with a caption test they cannot pass and a mutual overlap test switched off, they stay apart
    strict = FineConfig(caption_similarity=0.999, overlap_alone=1.0)
    assert fine_merge(masks, halves, strict) == halves


def test_fine_merge_keeps_a_rug_apart_from_the_floor_unless_openobj_rule(encoder):
    # a narrow runner: every one of its points is within 0.05 m of the floor around it
    floor, rug = [-1.0, -1.0, -0.02, 2.0, 1.0, 0.0], [-0.5, -0.04, 0.0, 1.5, 0.04, 0.01]
    frames = orbit([floor, rug], [(150, 120, 90), (20, 30, 120)], n=6, radius=2.0)
    segs = segment_frames(frames, {1: "the oak floor", 2: "a striped navy blue runner rug"}, encoder)
    masks = observe_masks(frames, segs, FusionConfig(min_mask_pixels=20, pixel_stride=1))  # dense floor
    by_id = [[m for m in range(len(masks)) if masks.source_ids[m][0] == k] for k in (1, 2)]
    assert fine_merge(masks, by_id) == by_id
    openobj = FineConfig(subset_caption_similarity=-1.0)  # OpenObj: overlap > 0.9 merges whatever it is
    assert len(fine_merge(masks, by_id, openobj)) == 1


def test_small_masks_and_masks_without_depth_are_dropped(two_objects, encoder):
    frames, segs = two_objects
    result = fuse_frames(frames, segs, FusionConfig(min_mask_pixels=10**6))
    assert result.instances == {} and result.assignment == {}
    assert not result.label_image(segs[0]).any()


def test_bad_input_raises_clear_errors(two_objects):
    frames, segs = two_objects
    with pytest.raises(ValueError, match="segmentations"):
        fuse_frames(frames, segs[:-1])
    shifted = [FrameSegmentation(s.frame_index + 1, s.labels, s.segments) for s in segs]
    with pytest.raises(ValueError, match="is for frame"):
        fuse_frames(frames, shifted)
    no_feature = [FrameSegmentation(s.frame_index, s.labels, [replace(g, caption_feature=None) for g in s.segments])
                  for s in segs]
    with pytest.raises(ValueError, match="caption_feature"):
        fuse_frames(frames, no_feature)
    with pytest.raises(ValueError, match="labels"):
        fuse_frames(frames[:1], [FrameSegmentation(segs[0].frame_index, segs[0].labels[:-1], segs[0].segments)])
    zero = [FrameSegmentation(s.frame_index, s.labels, [replace(g, caption_feature=np.zeros(384)) for g in s.segments])
            for s in segs]
    with pytest.raises(ValueError, match="non-zero"):
        fuse_frames(frames, zero)
    doubled = [FrameSegmentation(s.frame_index, s.labels, s.segments + s.segments[:1]) for s in segs]
    with pytest.raises(ValueError, match="unique"):
        fuse_frames(frames, doubled)
    with pytest.raises(ValueError, match="pixel_stride"):
        FusionConfig(pixel_stride=0)
    with pytest.raises(ValueError, match="communities"):
        fuse_frames(frames, segs, FusionConfig(coarse=CoarseConfig(communities="spectral")))


# ----------------------------------------------------------------------------------------------
# The simulated world: one agent, all its frames, ground-truth masks

def test_tiny_world_agent_fuses_to_its_visible_instances(tiny_world, encoder):
    cfg = FusionConfig()
    caps = {inst.instance_id: inst.caption for inst in tiny_world.scene.instances}
    frames = [tiny_world.render(0, i) for i in range(len(tiny_world.agent_poses[0]))]
    segs = segment_frames(frames, caps, encoder)
    result = fuse_frames(frames, segs, cfg)
    visible = set()
    for f in frames:
        ids, counts = np.unique(f.instance[f.depth > 0], return_counts=True)
        visible |= {int(i) for i, c in zip(ids, counts) if i > 0 and c >= cfg.min_mask_pixels}
    assert len(result.instances) == len(visible)
    # purity from the ground-truth pixels under each fused instance's masks
    pixels: dict[int, dict[int, int]] = {}
    for f, s in zip(frames, segs):
        local = result.label_image(s)
        for lid, gt in zip(local[local > 0], f.instance[local > 0]):
            pixels.setdefault(int(lid), {}).setdefault(int(gt), 0)
            pixels[int(lid)][int(gt)] += 1
    for lid, counts in pixels.items():
        dominant = max(counts, key=counts.get)
        assert counts[dominant] / sum(counts.values()) > 0.9
        assert result.instances[lid].source_ids[0] == dominant
    assert {max(c, key=c.get) for c in pixels.values()} == visible
