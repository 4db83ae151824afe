"""The simulated open-vocabulary front end: error model, segmenters, captioner, encoders, scene semantics."""

from __future__ import annotations

import sys
import warnings

import numpy as np
import pytest

from mapping.data import Frame, Intrinsics
from mapping.perception import (DatasetMaskSegmenter, ErrorPlan, FrameSegmentation, ImageEncoderError, InstanceInfo,
                                OracleSegmenter, SegmentationErrorConfig, TemplateCaptioner, VisualFeatureNotice,
                                crop_for_mask, encode_segments, load_image_encoder, plan_errors, wrong_category)
from mapping.perception import image_encoder as image_encoder_module
from mapping.perception.captioner import CONFUSABLE, SYNONYMS
from mapping.perception.errors import mask_dropped, split_labels

H, W = 60, 80
K = Intrinsics(W, H, 60.0, 60.0, 40.0, 30.0)
WALL, CHAIR, MUG, BOTTLE, SPECK = 1, 7, 8, 9, 10
INFOS = [
    InstanceInfo(WALL, "wall", "a white wall", "white", "painted", is_structure=True),
    InstanceInfo(CHAIR, "chair", "a red wooden chair", "red", "wooden"),
    InstanceInfo(MUG, "mug", "a white ceramic mug", "white", "ceramic", touching=(BOTTLE,)),
    InstanceInfo(BOTTLE, "bottle", "a green glass bottle", "green", "glass", touching=(MUG,)),
    InstanceInfo(SPECK, "box", "a tiny box", "brown", "cardboard"),
]


def instance_image(shift_px: int = 0) -> np.ndarray:
    """Wall everywhere; a 25x25 chair, a 20x15 mug touching a 20x20 bottle, a 6x10 speck (< 100 px)."""
    inst = np.full((H, W), WALL, np.int32)
    inst[5:30, 5 + shift_px:30 + shift_px] = CHAIR
    inst[35:55, 40:55] = MUG
    inst[35:55, 55:75] = BOTTLE
    inst[2:8, 60:70] = SPECK
    return inst


def make_frame(index: int = 0, inst: np.ndarray | None = None, x_m: float = 0.0) -> Frame:
    """A fronto-parallel scene 2 m away (identity pose, camera moved by ``x_m`` along x)."""
    pose = np.eye(4)
    pose[0, 3] = x_m
    return Frame(np.zeros((H, W, 3), np.uint8), np.full((H, W), 2.0, np.float32), pose, K,
                 instance=instance_image() if inst is None else inst, index=index)


class CategoryCaptioner:
    """Test double: the caption names the category the segmenter asked for, the instance and the piece."""

    def caption(self, info, agent, frame_index, category=None, variant=0):
        return f"{category or info.category}|{info.instance_id}|{variant}"


def oracle(errors=None, plan=None, **kw) -> OracleSegmenter:
    return OracleSegmenter(INFOS, errors or SegmentationErrorConfig.none(), CategoryCaptioner(), plan=plan, **kw)


def masks_by_source(seg: FrameSegmentation) -> dict[tuple[int, ...], list[np.ndarray]]:
    out: dict[tuple[int, ...], list[np.ndarray]] = {}
    for s in seg.segments:
        out.setdefault(s.source_ids, []).append(seg.labels == s.segment_id)
    return out


# ------------------------------------------------------------------ oracle segmenter, planted errors

def test_perfect_segmenter_gives_ground_truth_masks_and_drops_small_ones():
    seg = oracle().segment(make_frame(3))
    inst = instance_image()
    assert seg.frame_index == 3 and seg.labels.dtype == np.int32 and seg.labels.shape == (H, W)
    assert [s.segment_id for s in seg.segments] == list(range(1, len(seg.segments) + 1))
    masks = masks_by_source(seg)
    assert set(masks) == {(WALL,), (CHAIR,), (MUG,), (BOTTLE,)}  # the 60-px speck is dropped
    for (iid,), [mask] in masks.items():
        assert np.array_equal(mask, inst == iid)
    assert np.all(seg.labels[inst == SPECK] == 0)
    assert {s.caption for s in seg.segments} == {"wall|1|0", "chair|7|0", "mug|8|0", "bottle|9|0"}
    assert all(s.pixels == (seg.labels == s.segment_id).sum() for s in seg.segments)


def test_over_segmentation_splits_instance_into_pieces_whose_union_is_the_instance():
    plan = ErrorPlan(over_pieces={CHAIR: 3}, plane_angles={CHAIR: np.array([0.3, 0.3 + np.pi / 2])})
    seg = oracle(plan=plan).segment(make_frame())
    pieces = masks_by_source(seg)[(CHAIR,)]
    assert len(pieces) == 3
    union = np.logical_or.reduce(pieces)
    assert np.array_equal(union, instance_image() == CHAIR)
    assert sum(p.sum() for p in pieces) == union.sum()  # disjoint
    chair_captions = sorted(s.caption for s in seg.segments if s.source_ids == (CHAIR,))
    assert chair_captions == ["chair|7|0", "chair|7|1", "chair|7|2"]


def test_over_segmentation_planes_are_fixed_in_the_world_across_frames():
    plan = ErrorPlan(over_pieces={CHAIR: 2}, plane_angles={CHAIR: np.array([0.7, 2.0])})
    segmenter = oracle(plan=plan)
    # camera moved 0.2 m to -x: the chair moves 6 px to the right in the image
    frames = [make_frame(0), make_frame(1, instance_image(shift_px=6), x_m=-0.2)]
    world_labels = []
    for frame in frames:
        seg = segmenter.segment(frame)
        pts, lab = [], []
        for s in seg.segments:
            if s.source_ids == (CHAIR,):
                mask = seg.labels == s.segment_id
                pts.append(frame.backproject(mask=mask))
                lab.append(np.full(mask.sum(), s.caption.split("|")[2]))
        world_labels.append((np.vstack(pts), np.concatenate(lab)))
    (p0, l0), (p1, l1) = world_labels
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(p0).query(p1)
    close = dist < 0.01
    assert close.sum() > 300 and np.mean(l0[idx[close]] == l1[close]) > 0.97


def test_split_labels_cut_flat_objects_across_their_extent():
    rng = np.random.default_rng(0)
    rug = np.column_stack([rng.uniform(0, 2, 500), rng.uniform(0, 1, 500), np.zeros(500)])  # flat, z = 0
    labels = split_labels(rug, rug, np.array([0.0, np.pi / 2]), 3)
    counts = np.bincount(labels, minlength=3)
    assert np.all(counts > 50)
    with pytest.raises(ValueError, match="2 or 3 pieces"):
        split_labels(rug, rug, np.zeros(2), 4)


def test_under_segmentation_merges_touching_pair_with_caption_of_the_larger():
    plan = ErrorPlan(under_partner={MUG: BOTTLE, BOTTLE: MUG})
    seg = oracle(plan=plan).segment(make_frame())
    inst = instance_image()
    masks = masks_by_source(seg)
    assert (MUG,) not in masks and (BOTTLE,) not in masks
    [merged] = masks[(BOTTLE, MUG)]  # bottle has 400 px, mug 300: most pixels first
    assert np.array_equal(merged, (inst == MUG) | (inst == BOTTLE))
    [segment] = [s for s in seg.segments if s.source_ids == (BOTTLE, MUG)]
    assert segment.caption.startswith("bottle|9") and segment.pixels == 700


def test_under_segmented_partner_out_of_view_leaves_a_single_mask():
    inst = instance_image()
    inst[inst == BOTTLE] = WALL
    seg = oracle(plan=ErrorPlan(under_partner={MUG: BOTTLE, BOTTLE: MUG})).segment(make_frame(inst=inst))
    assert (MUG,) in masks_by_source(seg)


def test_semantic_error_describes_a_confusable_category_and_spares_structure():
    seg = oracle(SegmentationErrorConfig(semantic_rate=1.0, over_segmentation_rate=0, under_segmentation_rate=0,
                                         mask_drop_rate=0)).segment(make_frame())
    captions = {s.source_ids[0]: s.caption.split("|")[0] for s in seg.segments}
    assert captions[CHAIR] in CONFUSABLE["chair"]
    assert captions[MUG] in CONFUSABLE["mug"] and captions[BOTTLE] in CONFUSABLE["bottle"]
    assert captions[WALL] == "wall"


def test_semantic_errors_hit_truncated_views_only_by_default():
    """A confused chair is captioned right when the whole mask lies in the central region (eq. 1 = 1)
    and wrong when it reaches the border band; with the option off it is wrong in both views."""
    central = np.full((H, W), WALL, np.int32)
    central[15:40, 20:45] = CHAIR
    truncated = instance_image()  # the chair's mask reaches the top border band
    rates = dict(semantic_rate=1.0, over_segmentation_rate=0, under_segmentation_rate=0, mask_drop_rate=0)

    def chair_caption(errors, inst):
        seg = oracle(errors).segment(make_frame(inst=inst))
        return next(s.caption.split("|")[0] for s in seg.segments if s.source_ids == (CHAIR,))

    default = SegmentationErrorConfig(**rates)
    assert chair_caption(default, central) == "chair"
    assert chair_caption(default, truncated) in CONFUSABLE["chair"]
    always = SegmentationErrorConfig(**rates, semantic_errors_in_partial_views=False)
    assert chair_caption(always, central) in CONFUSABLE["chair"]


def test_mask_drop_removes_visible_objects_but_not_structure():
    errors = SegmentationErrorConfig(0, 0, 0, mask_drop_rate=1.0)
    seg = oracle(errors).segment(make_frame())
    assert set(masks_by_source(seg)) == {(WALL,)}


def test_persistent_errors_are_the_same_in_every_frame_and_drops_vary():
    errors = SegmentationErrorConfig(semantic_rate=0.5, over_segmentation_rate=0, under_segmentation_rate=0,
                                     mask_drop_rate=0.5)
    segmenter = OracleSegmenter(INFOS, errors, CategoryCaptioner(), seed=3, agent=1)
    chair_captions, chair_seen = set(), []
    for i in range(40):
        seg = segmenter.segment(make_frame(i))
        chair = [s.caption.split("|")[0] for s in seg.segments if s.source_ids == (CHAIR,)]
        chair_seen.append(bool(chair))
        chair_captions.update(chair)
    assert len(chair_captions) == 1  # right or wrong, always the same category
    assert 5 < sum(chair_seen) < 35  # dropped in some frames only


def test_same_seed_and_agent_give_identical_output_other_agents_differ():
    errors = SegmentationErrorConfig(0.5, 0.3, 0.5, 0.3)
    a = OracleSegmenter(INFOS, errors, TemplateCaptioner(5), seed=5, agent=2).segment(make_frame(4))
    b = OracleSegmenter(INFOS, errors, TemplateCaptioner(5), seed=5, agent=2).segment(make_frame(4))
    assert np.array_equal(a.labels, b.labels)
    assert [(s.caption, s.source_ids) for s in a.segments] == [(s.caption, s.source_ids) for s in b.segments]
    many = [InstanceInfo(i, "chair", "", touching=(i + 1,) if i % 2 else (i - 1,)) for i in range(1, 201)]
    plans = [plan_errors(many, SegmentationErrorConfig(), seed=5, agent=k) for k in range(3)]
    again = plan_errors(many, SegmentationErrorConfig(), seed=5, agent=0)
    assert (again.wrong_category, again.over_pieces, again.under_partner) == \
        (plans[0].wrong_category, plans[0].over_pieces, plans[0].under_partner)
    assert all(np.array_equal(again.plane_angles[i], plans[0].plane_angles[i]) for i in again.plane_angles)
    keys = [(set(p.wrong_category), set(p.over_pieces), set(p.under_partner)) for p in plans]
    assert keys[0] != keys[1] and keys[1] != keys[2]


def test_error_rates_over_many_instances_match_the_configuration():
    n = 4000  # pairs (1, 2), (3, 4), ... touch; every 10th instance is structure
    infos = [InstanceInfo(i, "chair", "", is_structure=(i % 10 == 0),
                          touching=(i + 1,) if i % 2 else (i - 1,)) for i in range(1, n + 1)]
    config = SegmentationErrorConfig()
    plan = plan_errors(infos, config, seed=11, agent=0)
    objects = [i.instance_id for i in infos if not i.is_structure]
    eligible = [i.instance_id for i in infos if not i.is_structure and not any(
        t % 10 == 0 for t in i.touching)]
    assert not any(i % 10 == 0 for i in set(plan.wrong_category) | set(plan.over_pieces) | set(plan.under_partner))
    assert abs(len(plan.wrong_category) / len(objects) - config.semantic_rate) < 0.025
    assert abs(len(plan.under_partner) / len(eligible) - config.under_segmentation_rate) < 0.025
    assert abs(len(plan.over_pieces) / len(objects) - config.over_segmentation_rate) < 0.025
    assert set(plan.over_pieces.values()) == {2, 3} and not set(plan.over_pieces) & set(plan.under_partner)
    assert all(plan.under_partner[plan.under_partner[i]] == i for i in plan.under_partner)
    drops = np.mean([mask_dropped(config, 11, 0, f, i) for f in range(20) for i in range(1, 201)])
    assert abs(drops - config.mask_drop_rate) < 0.02


def test_bad_inputs_raise_clear_errors():
    with pytest.raises(ValueError, match="semantic_rate"):
        SegmentationErrorConfig(semantic_rate=1.5)
    with pytest.raises(ValueError, match="no instance image"):
        oracle().segment(Frame(np.zeros((H, W, 3), np.uint8), np.ones((H, W), np.float32), np.eye(4), K))
    inst = instance_image()
    inst[0, 0] = 99
    with pytest.raises(ValueError, match=r"\[99\]"):
        oracle().segment(make_frame(inst=inst))
    with pytest.raises(ValueError, match="unique"):
        plan_errors(INFOS + INFOS[:1], SegmentationErrorConfig(), 0, 0)


# ------------------------------------------------------------------ dataset masks

def test_dataset_mask_segmenter_relabels_ids_and_uses_captions():
    inst = np.zeros((H, W), np.int32)
    inst[:20, :20] = 500
    inst[30:50, 30:50] = 3
    inst[55:58, :10] = 4  # 30 px: dropped
    seg = DatasetMaskSegmenter({500: "a grey sofa"}).segment(make_frame(inst=inst))
    assert [(s.segment_id, s.source_ids, s.caption, s.pixels) for s in seg.segments] == [
        (1, (3,), "an object", 400), (2, (500,), "a grey sofa", 400)]
    assert np.array_equal(seg.labels == 2, inst == 500) and np.all(seg.labels[inst == 4] == 0)
    full = np.full((H, W), 7, np.int32)  # no background pixel at all
    only = DatasetMaskSegmenter().segment(make_frame(inst=full))
    assert len(only.segments) == 1 and np.all(only.labels == 1)


# ------------------------------------------------------------------ captioner

def test_captioner_varies_phrasing_but_keeps_to_metadata():
    info = InstanceInfo(7, "sofa", "a dark green velvet couch", "dark green", "velvet")
    captions = {TemplateCaptioner(seed).caption(info, agent=0, frame_index=0) for seed in range(30)}
    assert len(captions) >= 3
    nouns = SYNONYMS["sofa"]
    assert all(any(n in c for n in nouns) for c in captions)
    assert all("an dark" not in c and "a a" not in c for c in captions)
    same = TemplateCaptioner(4).caption(info, 1, 9), TemplateCaptioner(4).caption(info, 1, 9)
    assert same[0] == same[1]
    wrong = {TemplateCaptioner(s).caption(info, 0, 0, category="armchair") for s in range(20)}
    assert all(any(n in c for n in SYNONYMS["armchair"]) and "couch" not in c for c in wrong)


def test_wrong_category_falls_back_to_scene_categories():
    rng = np.random.default_rng(0)
    assert wrong_category("chair", rng) in CONFUSABLE["chair"]
    assert wrong_category("robot", rng, ["robot", "wall", "fridge"]) == "fridge"
    assert wrong_category("robot", rng, ["robot"]) == "object"


# ------------------------------------------------------------------ image encoder interface, front end

def test_no_checkpoint_gives_none_and_a_single_notice(monkeypatch):
    monkeypatch.setattr(image_encoder_module, "_notice_given", False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert load_image_encoder(None) is None
        assert load_image_encoder(None) is None
    notices = [w for w in caught if issubclass(w.category, VisualFeatureNotice)]
    assert len(notices) == 1 and "weighs 0" in str(notices[0].message)


def test_missing_checkpoint_or_open_clip_are_clear_errors(tmp_path, monkeypatch):
    missing = tmp_path / "nope.pt"
    with pytest.raises(FileNotFoundError, match="nope.pt"):
        load_image_encoder(missing)
    ckpt = tmp_path / "clip.pt"
    ckpt.write_bytes(b"0")
    monkeypatch.setitem(sys.modules, "open_clip", None)  # import fails as if not installed
    with pytest.raises(ImageEncoderError, match=r"pip install openmulti\[clip\]"):
        load_image_encoder(ckpt)


def test_crop_for_mask_pads_and_clips_to_the_image():
    rgb = np.arange(H * W * 3, dtype=np.uint8).reshape(H, W, 3)
    mask = np.zeros((H, W), bool)
    mask[30:35, 2:6] = True
    crop = crop_for_mask(rgb, mask, pad_px=20)
    assert crop.shape == (45, 26, 3) and np.array_equal(crop, rgb[10:55, 0:26])
    with pytest.raises(ValueError, match="empty"):
        crop_for_mask(rgb, np.zeros((H, W), bool))


class TinyImageEncoder:
    """Test double of an image-text encoder: mean crop colour plus a constant, normalised."""

    dim = 4

    def encode_images(self, crops):
        f = np.array([[*c.reshape(-1, 3).mean(axis=0), 1.0] for c in crops], np.float32)
        return f / np.linalg.norm(f, axis=1, keepdims=True)

    def encode_texts(self, texts):
        return np.tile(np.array([[0, 0, 0, 1.0]], np.float32), (len(texts), 1))


@pytest.fixture(scope="session")
def text_encoder():
    from mapping.perception import shared_text_encoder

    return shared_text_encoder()


def test_text_encoder_is_offline_and_ranks_by_meaning(text_encoder):
    v = text_encoder.encode(["chair", "something to sit on", "lamp"])
    assert v.shape == (3, text_encoder.dim) and np.allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5)
    assert v[0] @ v[1] > v[0] @ v[2]


def test_encode_segments_fills_caption_and_visual_features(text_encoder):
    frame = make_frame()
    seg = OracleSegmenter(INFOS, SegmentationErrorConfig.none(), seed=0).segment(frame)
    out = encode_segments(seg, frame, text_encoder)
    assert out is seg
    assert all(s.caption_feature.shape == (text_encoder.dim,) and s.visual_feature is None for s in seg.segments)
    expected = text_encoder.encode([s.caption for s in seg.segments])
    assert np.allclose(np.stack([s.caption_feature for s in seg.segments]), expected)
    encode_segments(seg, frame, text_encoder, TinyImageEncoder())
    assert all(s.visual_feature.shape == (4,) for s in seg.segments)


# ------------------------------------------------------------------ scene semantics and the simulator

def test_instance_infos_of_the_tiny_scene(tiny_scene):
    from openmulti_env.world.semantics import instance_infos

    infos = instance_infos(tiny_scene)
    assert [i.instance_id for i in infos] == [inst.instance_id for inst in tiny_scene.instances]
    by_id = {i.instance_id: i for i in infos}
    for inst in tiny_scene.instances:
        info = by_id[inst.instance_id]
        assert (info.category, info.caption, info.is_structure) == (inst.category, inst.caption, inst.is_structure)
        if inst.is_structure:
            assert info.touching == ()
        if inst.support_id:  # small objects touch what they rest on
            assert inst.support_id in info.touching
        assert all(inst.instance_id in by_id[j].touching for j in info.touching)
    assert any(i.touching for i in infos)


def test_oracle_segmenter_on_a_rendered_frame(tiny_world):
    from openmulti_env.world.semantics import instance_anchor_points, instance_infos

    frame = tiny_world.render(0, 0)
    infos = instance_infos(tiny_world.scene)
    segmenter = OracleSegmenter(infos, SegmentationErrorConfig(), seed=0, agent=0,
                                anchor_points=instance_anchor_points(tiny_world.scene))
    seg = segmenter.segment(frame)
    ids = {i.instance_id for i in infos}
    assert seg.segments and all(set(s.source_ids) <= ids and s.pixels >= 100 for s in seg.segments)
    assert set(np.unique(seg.labels)) - {0} == {s.segment_id for s in seg.segments}
