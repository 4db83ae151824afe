"""Cross-agent instance alignment (sec. III-C) on hand-made clouds, FusionResults and frames: the overlap
and graph of ``mapping.alignment`` and the batch alignment of ``studies.batch_alignment``."""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mapping.alignment import AlignmentConfig, InstanceCollaborativeGraph, iob, iou
from mapping.alignment.overlap import directed_overlap_count, pairwise_overlap_counts
from mapping.data.frame import Frame, Intrinsics
from mapping.perception.types import AgentInstance, FrameSegmentation, FusionResult, Segment
from mapping.pointcloud import voxel_downsample
from studies.batch_alignment import align_agents, id_consistency, id_purity, no_alignment, oracle_alignment
from studies.batch_alignment.messages import instance_message_bytes


@pytest.fixture(scope="session")
def encoder():
    from mapping.perception.text_encoder import shared_text_encoder

    return shared_text_encoder()


# ------------------------------------------------------------------------------------------ builders
def box_surface(center, size, rng, spacing=0.008, keep=None):
    """Random points on the surface of an axis-aligned box, about one per spacing^2; ``keep`` filters."""
    center, size = np.asarray(center, float), np.asarray(size, float)
    points = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        area = size[others[0]] * size[others[1]]
        for sign in (-1, 1):
            n = int(area / spacing**2)
            p = rng.uniform(-0.5, 0.5, (n, 3)) * size
            p[:, axis] = sign * size[axis] / 2
            points.append(p + center)
    points = np.concatenate(points)
    return points if keep is None else points[keep(points)]


def instance(lid, points, caption="a chair", confidence=0.5, feature=None, source=(), observations=(), visual=None):
    if feature is None:
        feature = np.zeros(384, np.float32)
        feature[zlib.crc32(caption.encode()) % 384] = 1.0  # stable across processes, unlike hash()
    return AgentInstance(lid, caption, np.asarray(feature, np.float32), visual, confidence, np.asarray(points, float),
                         np.full(3, 0.5), list(observations), tuple(source))


def fusion(*instances):
    return FusionResult({i.local_id: i for i in instances},
                        {obs: i.local_id for i in instances for obs in i.observations})


def plane_frame(index=0):
    """A fronto-parallel plane 2 m in front of a camera at the origin: 40 x 30 pixels of 1 cm each."""
    k = Intrinsics(40, 30, 200.0, 200.0, 19.5, 14.5)
    return Frame(np.zeros((30, 40, 3), np.uint8), np.full((30, 40), 2.0, np.float32), np.eye(4), k, index=index)


# ------------------------------------------------------------------------------------------ overlap
def test_iou_iob_on_hand_made_clouds():
    line = lambda start, n: np.c_[0.02 * np.arange(start, start + n), np.zeros(n), np.zeros(n)]
    a, half, far = line(0, 10), line(5, 10), line(100, 10)
    assert iou(a, a, 0.01) == 1.0 and iob(a, a, 0.01) == 1.0
    assert iou(a, half, 0.01) == pytest.approx(5 / 15) and iob(a, half, 0.01) == pytest.approx(0.5)
    assert iou(a, far, 0.01) == 0.0 and iob(a, far, 0.01) == 0.0
    sub = line(2, 4)
    assert iob(sub, a, 0.01) == 1.0 and iob(a, sub, 0.01) == pytest.approx(0.4)
    assert iou(sub, a, 0.01) == pytest.approx(0.4) == iou(a, sub, 0.01)
    assert iob(np.zeros((0, 3)), a) == 0.0
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        iou(np.zeros((4, 2)), a)
    with pytest.raises(ValueError, match="NaN"):
        iob(np.full((2, 3), np.nan), a)


def test_pairwise_counts_match_pair_by_pair():
    rng = np.random.default_rng(1)
    clouds_a = [rng.uniform(0, 0.3, (50, 3)), rng.uniform(0.2, 0.5, (30, 3)), np.zeros((0, 3))]
    clouds_b = [rng.uniform(0.1, 0.4, (40, 3)), rng.uniform(2, 3, (20, 3))]
    n_ab, n_ba = pairwise_overlap_counts(clouds_a, clouds_b, 0.05)
    for i, a in enumerate(clouds_a):
        for j, b in enumerate(clouds_b):
            assert n_ab[i, j] == directed_overlap_count(a, b, 0.05)
            assert n_ba[i, j] == directed_overlap_count(b, a, 0.05)
    assert n_ab[0, 0] > 0 and n_ab[0, 1] == 0


def test_voxel_downsample_keeps_one_centroid_per_voxel():
    points = np.array([[0.001, 0.001, 0.001], [0.009, 0.009, 0.009], [0.031, 0.0, 0.0]])
    out = voxel_downsample(points, 0.02)
    np.testing.assert_allclose(out, [[0.005, 0.005, 0.005], [0.031, 0.0, 0.0]])
    with pytest.raises(ValueError, match="voxel size"):
        voxel_downsample(points, 0.0)


def test_bytes_follow_the_message_formula():
    centres = lambda n, x0: np.c_[x0 + 0.02 * np.arange(n) + 0.01, np.full(n, 0.01), np.full(n, 0.01)]
    visual = np.ones(512, np.float32) / np.sqrt(512)
    fused = {"agent_0": fusion(instance(1, centres(10, 0.0)), instance(2, centres(3, 5.0), visual=visual)),
             "agent_1": fusion(instance(1, centres(7, 10.0))),
             "agent_2": fusion(instance(4, centres(5, 20.0)))}
    payload = {"agent_0": 4 * (3 * 10 + 384 + 1) + 4 + 4 * (3 * 3 + 384 + 512 + 1) + 4,
               "agent_1": 4 * (3 * 7 + 384 + 1) + 4, "agent_2": 4 * (3 * 5 + 384 + 1) + 4}
    assert instance_message_bytes(10, 384, None) == 4 * (3 * 10 + 384 + 1) + 4
    result = align_agents(fused)
    assert result.bytes_sent == {a: 2 * p for a, p in payload.items()}
    assert result.bytes_per_link[("agent_0", "agent_2")] == payload["agent_0"] + payload["agent_2"]
    only = align_agents(fused, links=[("agent_1", "agent_0")])
    assert only.bytes_sent == {"agent_0": payload["agent_0"], "agent_1": payload["agent_1"], "agent_2": 0}
    assert list(only.bytes_per_link) == [("agent_0", "agent_1")]
    with pytest.raises(ValueError, match="bad link"):
        align_agents(fused, links=[("agent_0", "agent_9")])


# --------------------------------------------------------------------------------------- the four errors
def test_semantic_error_takes_the_reference_caption(encoder):
    rng = np.random.default_rng(2)
    chair, table = ([0, 0, 0.4], [0.4, 0.4, 0.8]), ([2, 0, 0.4], [1.0, 0.6, 0.8])
    feats = dict(zip(["a wooden chair", "a lamp", "a white table"],
                     encoder.encode(["a wooden chair", "a lamp", "a white table"])))
    fused = {"agent_0": fusion(instance(3, box_surface(*chair, rng), "a wooden chair", 0.9, feats["a wooden chair"]),
                               instance(5, box_surface(*table, rng), "a white table", 0.4, feats["a white table"])),
             "agent_1": fusion(instance(1, box_surface(*chair, rng), "a lamp", 0.3, feats["a lamp"]),
                               instance(2, box_surface(*table, rng), "a white table", 0.7, feats["a white table"]))}
    result = align_agents(fused)
    a0, a1 = result.agents["agent_0"], result.agents["agent_1"]
    assert a0.local_to_global == {3: 1, 5: 2} and a1.local_to_global == {1: 1, 2: 2}
    assert a1.codebook[1].caption == "a wooden chair" and a1.codebook[1].confidence == 0.9
    np.testing.assert_array_equal(a1.codebook[1].caption_feature, feats["a wooden chair"])
    np.testing.assert_array_equal(a1.instances[1].points, fused["agent_1"].instances[1].points)  # own geometry
    assert a0.codebook[2].caption == "a white table" and a0.codebook[2].confidence == 0.7


def test_over_segmentation_pieces_share_one_global_id():
    rng = np.random.default_rng(3)
    box = box_surface([0, 0, 0.3], [0.5, 0.3, 0.6], rng)
    other = box_surface([0, 0, 0.3], [0.5, 0.3, 0.6], rng)
    fused = {"agent_0": fusion(instance(1, box, "a cabinet", 0.9)),
             "agent_1": fusion(instance(1, other[other[:, 0] < 0], "a door", 0.3, observations=[(0, 1)]),
                               instance(2, other[other[:, 0] >= 0], "a handle", 0.4, observations=[(0, 2)]))}
    labels = np.zeros((30, 40), np.int32)
    labels[5:25, 5:20], labels[5:25, 20:35] = 1, 2
    segs = {"agent_1": [FrameSegmentation(0, labels, [Segment(1, "a door", 300), Segment(2, "a handle", 300)])]}
    result = align_agents(fused, segmentations=segs)
    a1 = result.agents["agent_1"]
    assert a1.local_to_global == {1: 1, 2: 1} and list(a1.instances) == [1]
    assert len(a1.instances[1].points) == len(other) and a1.instances[1].caption == "a cabinet"
    assert a1.instances[1].observations == [(0, 1), (0, 2)]
    np.testing.assert_array_equal(a1.corrected_labels(0), np.where(labels > 0, 1, 0))


def test_viewpoint_loss_joins_the_full_instance():
    rng = np.random.default_rng(4)
    sofa = ([1, 1, 0.4], [1.2, 0.5, 0.8])
    part = box_surface(*sofa, rng, keep=lambda p: (p[:, 0] > 0.41) & (p[:, 0] < 0.6))  # a slice of one end
    fused = {"agent_0": fusion(instance(1, box_surface(*sofa, rng), "a grey sofa", 0.8)),
             "agent_1": fusion(instance(7, part, "a pillow", 0.2))}
    graph_iou = iou(voxel_downsample(part, 0.02), voxel_downsample(fused["agent_0"].instances[1].points, 0.02))
    assert graph_iou < AlignmentConfig().iou_threshold  # only the IoB edge can join them
    result = align_agents(fused)
    assert result.agents["agent_1"].local_to_global == {7: 1}
    assert result.agents["agent_1"].codebook[1].caption == "a grey sofa"
    assert len(result.clusters) == 1 and result.clusters[1].reference == ("agent_0", 1, 0)


def _under_segmented_team(u_confidence=0.3, right_confidence=0.8):
    """agent_0 sees two patches of a plane (left, right); agent_1 sees both as one instance."""
    frame = plane_frame(0)
    left, right = np.zeros((30, 40), bool), np.zeros((30, 40), bool)
    left[:, :20], right[:, 20:] = True, True
    labels0 = np.where(left, 1, 2).astype(np.int32)
    labels1 = np.zeros((30, 40), np.int32)
    labels1[3:27, 2:38] = 1
    fused = {"agent_0": fusion(instance(1, frame.backproject(mask=left), "a blue mug", 0.9, observations=[(0, 1)],
                                        source=(11,)),
                               instance(2, frame.backproject(mask=right), "a red mug", right_confidence,
                                        observations=[(0, 2)],
                                        source=(12,))),
             "agent_1": fusion(instance(4, frame.backproject(mask=labels1 > 0), "two mugs", u_confidence,
                                        observations=[(0, 1)], source=(11, 12)))}
    segs = {"agent_0": [FrameSegmentation(0, labels0, [Segment(1, "a blue mug", 600, source_ids=(11,)),
                                                       Segment(2, "a red mug", 600, source_ids=(12,))])],
            "agent_1": [FrameSegmentation(0, labels1, [Segment(1, "two mugs", 864, source_ids=(11, 12))])]}
    gt = np.where(left, 11, 12).astype(np.int32)
    frames = {a: [Frame(frame.rgb, frame.depth, frame.pose, frame.intrinsics, gt, index=0)] for a in fused}
    return fused, frames, segs, labels1


def test_under_segmentation_is_split_into_the_references_masks():
    fused, frames, segs, labels1 = _under_segmented_team()
    result = align_agents(fused, frames, segs)
    a0, a1 = result.agents["agent_0"], result.agents["agent_1"]
    assert a0.local_to_global == {1: 1, 2: 2}
    assert 4 not in a1.local_to_global and a1.split == {4: (1, 2)} and a1.global_ids_of(4) == (1, 2)
    expected = np.zeros((30, 40), np.int32)
    expected[3:27, 2:20], expected[3:27, 20:38] = 1, 2
    np.testing.assert_array_equal(a1.corrected_labels(0), expected)
    np.testing.assert_array_equal(a0.corrected_labels(0), np.where(np.arange(40) < 20, 1, 2)[None].repeat(30, 0))
    assert a1.codebook[1].caption == "a blue mug" and a1.codebook[2].caption == "a red mug"
    assert np.all(a1.instances[1].points[:, 0] < 0) and np.all(a1.instances[2].points[:, 0] > 0)
    with pytest.raises(ValueError, match="needs the agent's frames"):
        align_agents(fused, None, segs).agents["agent_1"].corrected_labels(0)
    with pytest.raises(ValueError, match="no segmentation for frame 5"):
        a1.corrected_labels(5)


def test_split_pieces_carry_their_references_meaning_whatever_the_confidences():
    """The merged mask (0.5) is more confident than the red mug (0.2) but less than the blue one (0.9):
    it is split, and its red piece must not outrank agent_0's red mug as the reference ("two mugs"
    would then become the red mug's caption for everyone)."""
    fused, frames, segs, _ = _under_segmented_team(u_confidence=0.5, right_confidence=0.2)
    result = align_agents(fused, frames, segs)
    a0, a1 = result.agents["agent_0"], result.agents["agent_1"]
    assert a1.split == {4: (1, 2)}
    for book in (a0.codebook, a1.codebook, result.codebook):
        assert book[1].caption == "a blue mug" and book[2].caption == "a red mug"
    assert result.codebook[2].confidence <= 0.2 + 1e-9


def test_confident_coarse_instance_merges_the_pieces_instead():
    fused, frames, segs, labels1 = _under_segmented_team(u_confidence=0.95)
    result = align_agents(fused, frames, segs)
    assert result.agents["agent_1"].local_to_global == {4: 1} and result.agents["agent_1"].split == {}
    assert result.agents["agent_0"].local_to_global == {1: 1, 2: 1}
    assert result.codebook[1].caption == "two mugs"


def test_points_far_from_every_reference_keep_an_id_of_their_own():
    rng = np.random.default_rng(5)
    boxes = [([x, 0, 0.1], [0.2, 0.2, 0.2]) for x in (0.0, 0.3, 0.6)]
    merged = np.concatenate([box_surface(*b, rng) for b in boxes])
    fused = {"agent_0": fusion(*[instance(i + 1, box_surface(*b, rng), f"box {i}", 0.9)
                                 for i, b in enumerate(boxes[:2])]),
             "agent_1": fusion(instance(1, merged, "boxes", 0.2))}
    a1 = align_agents(fused).agents["agent_1"]
    assert a1.split == {1: (1, 2, 3)}
    assert np.all(a1.instances[3].points[:, 0] > 0.45) and a1.codebook[3].caption == "boxes"


def test_unlinked_agents_are_not_aligned():
    rng = np.random.default_rng(6)
    box = ([0, 0, 0.2], [0.3, 0.3, 0.4])
    fused = {f"agent_{k}": fusion(instance(1, box_surface(*box, rng), "a bin", 0.2 + 0.1 * k)) for k in range(3)}
    result = align_agents(fused, links=[("agent_0", "agent_1")])
    assert {a: r.local_to_global[1] for a, r in result.agents.items()} == {"agent_0": 1, "agent_1": 1, "agent_2": 2}
    chained = align_agents(fused, links=[("agent_0", "agent_1"), ("agent_1", "agent_2")])
    assert {r.local_to_global[1] for r in chained.agents.values()} == {1}


# ------------------------------------------------------------------------------- ablation and oracle
def test_no_alignment_gives_disjoint_ids():
    fused, frames, segs, _ = _under_segmented_team()
    result = no_alignment(fused, frames, segs)
    assert result.agents["agent_0"].local_to_global == {1: 1, 2: 2}
    assert result.agents["agent_1"].local_to_global == {4: 3} and result.bytes_sent == {"agent_0": 0, "agent_1": 0}
    assert result.agents["agent_1"].codebook[3].caption == "two mugs"
    assert set(np.unique(result.agents["agent_1"].corrected_labels(0))) == {0, 3}
    assert id_consistency(result, fused) == 0.0


def test_oracle_is_consistent_and_splits_masks_by_ground_truth():
    fused, frames, segs, labels1 = _under_segmented_team()
    result = oracle_alignment(fused, frames, segs)
    assert id_consistency(result, fused) == 1.0
    assert result.agents["agent_0"].local_to_global == {1: 11, 2: 12}
    expected = np.where(labels1 > 0, np.where(np.arange(40) < 20, 11, 12)[None], 0)
    np.testing.assert_array_equal(result.agents["agent_1"].corrected_labels(0), expected)
    assert result.codebook[12].caption == "a red mug"
    bad = {"agent_0": fusion(instance(1, np.zeros((3, 3))))}
    with pytest.raises(ValueError, match="no source_ids"):
        oracle_alignment(bad)


# ---------------------------------------------------------------- property: random scenes, planted errors
def _random_team(seed):
    """Boxes on a grid; every box seen whole by a confident agent, errors planted in the others.

    Returns the team's fusion results and, per box, its ground-truth points (for purity checks).
    """
    rng = np.random.default_rng(seed)
    n_agents, n_boxes = int(rng.integers(2, 5)), int(rng.integers(3, 7))
    names = [f"agent_{k}" for k in range(n_agents)]
    boxes = [(np.array([0.7 * (b % 3), 0.7 * (b // 3), 0.2]), rng.uniform(0.15, 0.4, 3)) for b in range(n_boxes)]
    views: dict[str, list[tuple[np.ndarray, str, float, tuple[int, ...]]]] = {a: [] for a in names}
    owners = {}
    for b, (c, s) in enumerate(boxes, start=1):
        owner = owners[b] = names[int(rng.integers(n_agents))]
        views[owner].append((box_surface(c, s, rng), f"box {b}", rng.uniform(0.6, 1.0), (b,)))
        for a in names:
            if a == owner or rng.random() < 0.3:
                continue
            pts, kind = box_surface(c, s, rng), rng.choice(["none", "semantic", "over", "viewpoint"])
            low = rng.uniform(0.05, 0.45)
            if kind == "over":
                cut = pts[:, 1] < c[1]
                views[a] += [(pts[cut], f"box {b} part", low, (b,)), (pts[~cut], f"box {b} part", low, (b,))]
            elif kind == "viewpoint":
                views[a].append((pts[pts[:, 0] < c[0] + s[0] * 0.1], f"box {b}", low, (b,)))
            else:
                views[a].append((pts, "junk" if kind == "semantic" else f"box {b}", low if kind != "none" else
                                 rng.uniform(0.05, 1.0), (b,)))
    # under-segmentation: an agent merges its views of two boxes that one confident owner saw apart
    for a in names:
        whole = [v for v in views[a] if v[2] < 0.5 and v[1] == f"box {v[3][0]}"]
        pairs = [(v1, v2) for i, v1 in enumerate(whole) for v2 in whole[i + 1:] if owners[v1[3][0]] == owners[v2[3][0]]]
        if pairs and rng.random() < 0.7:
            v1, v2 = pairs[0]
            views[a] = [v for v in views[a] if v is not v1 and v is not v2]
            views[a].append((np.concatenate([v1[0], v2[0]]), "two boxes", min(v1[2], v2[2]), v1[3] + v2[3]))
    fused = {}
    for a in names:
        order = rng.permutation(len(views[a]))
        fused[a] = fusion(*[instance(i + 1, *views[a][j][:3], source=views[a][j][3]) for i, j in enumerate(order)])
    truth = [box_surface(c, s, rng) for c, s in boxes]
    return fused, truth


@pytest.mark.parametrize("seed", range(8))
def test_random_scenes_align_injectively_and_consistently(seed):
    fused, truth = _random_team(seed)
    tree = cKDTree(np.concatenate(truth))
    owner = np.repeat(np.arange(1, len(truth) + 1), [len(t) for t in truth])
    result = align_agents(fused)
    global_to_box: dict[int, set[int]] = {}
    for a, al in result.agents.items():
        box_to_global: dict[int, set[int]] = {}
        for gid, inst in al.instances.items():
            boxes = set(owner[tree.query(inst.points)[1]])
            assert len(boxes) == 1, f"{a}: global id {gid} covers boxes {boxes}"
            global_to_box.setdefault(gid, set()).update(boxes)
            box_to_global.setdefault(boxes.pop(), set()).add(gid)
        assert all(len(g) == 1 for g in box_to_global.values()), f"{a}: one box under several ids {box_to_global}"
        assert set(al.codebook) == set(al.instances)
        ids = [*al.local_to_global.values(), *(g for gs in al.split.values() for g in gs)]
        assert set(ids) == set(al.instances)
    assert all(len(b) == 1 for b in global_to_box.values())  # one id, one box, in every agent
    assert sorted(result.codebook) == list(range(1, len(result.codebook) + 1))
    assert id_consistency(result, fused) == 1.0
    assert id_consistency(oracle_alignment(fused), fused) == 1.0


def test_bad_options_and_inputs_are_named():
    with pytest.raises(ValueError, match="iou_threshold"):
        AlignmentConfig(iou_threshold=0.0)
    with pytest.raises(ValueError, match="voxel_size_m"):
        AlignmentConfig(voxel_size_m=-1.0)
    with pytest.raises(ValueError, match="at least one agent"):
        align_agents({})
    nan_conf = {"agent_0": fusion(instance(1, np.zeros((2, 3)), confidence=float("nan")))}
    with pytest.raises(ValueError, match="non-finite confidence"):
        align_agents(nan_conf)
    with pytest.raises(ValueError, match="unknown agents"):
        align_agents({"agent_0": fusion(instance(1, np.zeros((2, 3))))}, segmentations={"agent_7": []})


# ------------------------------------------------------------------------------- partial-view edge
def wall_strip(x0, x1, spacing=0.01):
    """Points on a vertical wall (plane y = 0) from x0 to x1, 2 m high."""
    xs, zs = np.meshgrid(np.arange(x0, x1, spacing), np.arange(0.0, 2.0, spacing))
    return np.c_[xs.ravel(), np.zeros(xs.size), zs.ravel()]


def test_partial_views_sharing_a_strip_join_when_their_captions_agree():
    """Two agents see two halves of one wall that overlap by a 0.3 m strip (IoB 0.1): the paper's
    thresholds alone keep them apart; the semantic partial-view edge joins them, but only when the
    captions agree, and never for a wall and the floor that meet along a line."""
    left = instance(1, wall_strip(0.0, 3.0), "a white wall", 0.4, source=(3,))
    right = instance(1, wall_strip(2.7, 5.7), "a white wall", 0.3, source=(3,))
    xs, ys = np.meshgrid(np.arange(0.0, 5.0, 0.01), np.arange(0.0, 3.0, 0.01))
    floor = instance(2, np.c_[xs.ravel(), ys.ravel(), np.zeros(xs.size)], "the floor", 0.3, source=(1,))
    fused = {"agent_0": fusion(left), "agent_1": fusion(right, floor)}
    paper_only = align_agents(fused, config=AlignmentConfig(partial_iob_threshold=1.0))
    assert paper_only.agents["agent_0"].local_to_global[1] != paper_only.agents["agent_1"].local_to_global[1]
    result = align_agents(fused)
    a0, a1 = result.agents["agent_0"].local_to_global, result.agents["agent_1"].local_to_global
    assert a0[1] == a1[1] and a1[2] != a1[1]
    assert id_consistency(result, fused) == 1.0
    other = {"agent_0": fusion(left), "agent_1": fusion(instance(1, right.points, "a wooden door", 0.3, source=(3,)))}
    split_meaning = align_agents(other)
    assert split_meaning.agents["agent_0"].local_to_global[1] != split_meaning.agents["agent_1"].local_to_global[1]


def test_id_purity_drops_when_alignment_glues_two_objects():
    rng = np.random.default_rng(0)
    box = box_surface([0, 0, 0], [0.3, 0.3, 0.3], rng)
    other = box_surface([2, 0, 0], [0.3, 0.3, 0.3], rng)
    clean = {"agent_0": fusion(instance(1, box, source=(1,)), instance(2, other, "a table", source=(2,))),
             "agent_1": fusion(instance(1, box, source=(1,)))}
    assert id_purity(align_agents(clean), clean) == 1.0
    # the same cloud claimed to be a different object by agent_1: one id now covers objects 1 and 3
    glued = {"agent_0": fusion(instance(1, box, source=(1,))), "agent_1": fusion(instance(1, box, source=(3,)))}
    assert id_purity(align_agents(glued), glued) == 0.0
    assert id_purity(no_alignment(glued), glued) == 1.0


def test_a_picture_flat_on_a_wall_keeps_its_own_id():
    """A picture 1 cm in front of a wall is within the overlap radius of it everywhere (IoB 1): the
    paper's IoB edge alone would glue it to the wall; being 10x smaller and meaning something else,
    it keeps its own id, while the two agents' walls still join."""
    wall = wall_strip(0.0, 3.0)
    strip = wall_strip(1.0, 1.4)
    picture = strip[(strip[:, 2] > 1.0) & (strip[:, 2] < 1.5)] + [0.0, 0.01, 0.0]
    fused = {"agent_0": fusion(instance(1, wall, "a white wall", 0.3, source=(3,))),
             "agent_1": fusion(instance(1, wall, "a white wall", 0.4, source=(3,)),
                               instance(2, picture, "a framed picture", 0.5, source=(9,)))}
    result = align_agents(fused)
    a0, a1 = result.agents["agent_0"].local_to_global, result.agents["agent_1"].local_to_global
    assert a0[1] == a1[1] != a1[2]

    clouds = {("agent_0", 1, 0): voxel_downsample(wall, 0.02), ("agent_1", 2, 0): voxel_downsample(picture, 0.02)}
    features = {("agent_0", 1, 0): fused["agent_0"].instances[1].caption_feature,
                ("agent_1", 2, 0): fused["agent_1"].instances[2].caption_feature}
    for ratio, edges in ((10.0, 0), (1e9, 1)):  # the paper's IoB edge alone joins them
        graph = InstanceCollaborativeGraph(0.02, 0.25, 0.5, flat_size_ratio=ratio)
        graph.add_instances(clouds, {n: 0.5 for n in clouds}, features)
        assert graph.graph.number_of_edges() == edges
