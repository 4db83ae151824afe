"""Zero-shot labels, F-mIoU / F-mAcc, retrieval scoring and ``openmulti query`` on a hand-made run."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from mapping.evaluate import export_scene_mesh
from mapping.evaluate.retrieval import score_instances
from mapping.evaluate.semantic import (
    ground_truth_semantic_points,
    per_class_table,
    semantic_metrics,
    zero_shot_labels,
)
from mapping.perception import CodeBook, CodeBookEntry, shared_text_encoder
from openmulti_env.runs.cli import main
from openmulti_env.runs.query import query_slug


@pytest.fixture(scope="session")
def encoder():
    return shared_text_encoder()  # the CLI uses the same shared instance: loaded once


def make_book(encoder, captions: dict[int, str], visual: dict[int, np.ndarray] | None = None) -> CodeBook:
    feats = encoder.encode(list(captions.values()))
    visual = visual or {}
    return CodeBook({i: CodeBookEntry(c, f, visual.get(i), confidence=0.9) for (i, c), f in zip(captions.items(), feats)})


class OneHotImageEncoder:
    """Stand-in for a CLIP text tower: each known word maps to its own axis."""

    def __init__(self, words: list[str]):
        self.words = words

    def encode_texts(self, texts):
        out = np.full((len(texts), len(self.words)), 1e-3, np.float32)
        for r, t in enumerate(texts):
            for k, w in enumerate(self.words):
                if w in t:
                    out[r, k] = 1.0
        return out / np.linalg.norm(out, axis=1, keepdims=True)


# --- zero-shot labels ---------------------------------------------------------------------------

def test_zero_shot_labels_pick_the_category_named_by_the_caption(encoder):
    book = make_book(encoder, {1: "a wooden chair", 2: "a black metal floor lamp with a white shade",
                               3: "a double bed with a light blue duvet", 4: "a light oak wooden coffee table"})
    labels = zero_shot_labels(book, ["lamp", "chair", "bed", "coffee_table", "lamp"], encoder)
    assert labels == {1: "chair", 2: "lamp", 3: "bed", 4: "coffee_table"}  # names returned as given


def test_zero_shot_visual_term_outweighs_the_caption_when_present(encoder):
    cats = ["chair", "lamp"]
    image = OneHotImageEncoder(cats)
    lamp_visual = image.encode_texts(["lamp"])[0]
    book = make_book(encoder, {1: "a wooden chair", 2: "a wooden chair"}, visual={2: lamp_visual})
    assert zero_shot_labels(book, cats, encoder, image_encoder=image) == {1: "chair", 2: "lamp"}
    assert zero_shot_labels(book, cats, encoder, image_encoder=None) == {1: "chair", 2: "chair"}
    assert zero_shot_labels(book, cats, encoder, image_encoder=image, visual_weight=0.0)[2] == "chair"


def test_zero_shot_labels_reject_an_empty_vocabulary(encoder):
    with pytest.raises(ValueError, match="at least one category"):
        zero_shot_labels(make_book(encoder, {1: "a chair"}), [], encoder)


# --- F-mIoU / F-mAcc ----------------------------------------------------------------------------

def line(xs) -> np.ndarray:
    return np.array([[x, 0.0, 0.0] for x in xs])


def test_semantic_metrics_on_a_hand_labelled_case():
    gt = line([0, 1, 2, 3, 10, 11])
    gt_labels = ["a", "a", "a", "a", "b", "b"]
    recon = line([0, 1, 2, 3.1, 10, 11])
    ids = np.array([1, 1, 1, 2, 2, 2])  # the point at x=3 goes to instance 2 ("b"): one a->b error
    m = semantic_metrics(gt, gt_labels, recon, ids, {1: "a", 2: "b"})
    # a: TP 3, FN 1, FP 0 -> IoU 3/4, acc 3/4, freq 4/6; b: TP 2, FN 0, FP 1 -> IoU 2/3, acc 1, freq 2/6
    assert m.f_miou == pytest.approx(100 * (4 / 6 * 3 / 4 + 2 / 6 * 2 / 3))
    assert m.f_macc == pytest.approx(100 * (4 / 6 * 3 / 4 + 2 / 6 * 1))
    assert m.miou == pytest.approx(100 * (3 / 4 + 2 / 3) / 2)
    rows = {r.class_name: r for r in m.per_class}
    assert rows["a"].n_points == 4 and rows["b"].iou == pytest.approx(2 / 3) and rows["b"].acc == 1.0
    assert [r.class_name for r in m.per_class] == ["a", "b"]  # most frequent first
    table = per_class_table(m)
    assert "| a | 66.7 | 75.0 | 75.0 | 4 |" in table and "72.22" in table


def test_unlabelled_instances_count_as_unknown_misses_not_false_positives():
    gt = line([0, 1, 2, 3])
    m = semantic_metrics(gt, ["a", "a", "b", "b"], line([0, 1, 2, 3]), [1, 1, 7, 2], {1: "a", 2: "b"})
    rows = {r.class_name: r for r in m.per_class}
    assert rows["a"].iou == 1.0 and rows["b"].acc == 0.5 and rows["b"].iou == 0.5


def test_perfect_reconstruction_scores_100():
    gt = np.random.default_rng(0).uniform(0, 3, (300, 3))
    labels = np.array(["chair", "table", "floor"])[np.arange(300) % 3]
    ids = np.arange(300) % 3 + 1
    m = semantic_metrics(gt, labels, gt.copy(), ids, {1: "chair", 2: "table", 3: "floor"})
    assert m.f_miou == pytest.approx(100.0) and m.f_macc == pytest.approx(100.0)


def test_empty_reconstruction_scores_zero_without_nan():
    gt = line([0, 1, 2])
    m = semantic_metrics(gt, ["a", "b", "b"], np.zeros((0, 3)), np.zeros(0, int), {})
    assert (m.f_miou, m.f_macc, m.miou, m.macc) == (0.0, 0.0, 0.0, 0.0)
    assert all(np.isfinite([r.iou, r.acc]).all() for r in m.per_class)
    assert json.dumps(m.as_dict(), allow_nan=False)  # JSON-safe


def test_semantic_metrics_name_bad_input():
    with pytest.raises(ValueError, match="3 ground-truth labels for 2"):
        semantic_metrics(line([0, 1]), ["a", "b", "c"], line([0]), [1], {1: "a"})
    with pytest.raises(ValueError, match="gt_points is empty"):
        semantic_metrics(np.zeros((0, 3)), [], line([0]), [1], {1: "a"})
    with pytest.raises(ValueError, match="2 instance ids for 1"):
        semantic_metrics(line([0]), ["a"], line([0]), [1, 2], {1: "a"})


def test_ground_truth_points_are_area_weighted_with_their_category():
    small = trimesh.creation.box((1.0, 1.0, 1.0))
    big = trimesh.creation.box((2.0, 2.0, 2.0))
    big.apply_translation((5.0, 0.0, 0.0))
    points, labels = ground_truth_semantic_points([(small, "mug"), (big, "bed")], n_points=5000, seed=3)
    assert points.shape == (5000, 3) and labels.shape == (5000,)
    share_bed = np.mean(labels == "bed")
    assert share_bed == pytest.approx(0.8, abs=0.03)  # areas 24 vs 6
    assert np.all(points[labels == "bed", 0] > 3.9) and np.all(points[labels == "mug", 0] < 0.6)
    again, _ = ground_truth_semantic_points([(small, "mug"), (big, "bed")], n_points=5000, seed=3)
    np.testing.assert_array_equal(points, again)


# --- retrieval ----------------------------------------------------------------------------------

CAPTIONS = {1: "a wooden chair", 2: "a soft double bed", 3: "a black metal floor lamp",
            4: "a white ceramic coffee mug", 5: "a tall wooden bookcase"}


def test_functional_query_ranks_the_bed_first(encoder):
    hits = score_instances("somewhere to sleep", make_book(encoder, CAPTIONS), encoder)
    assert hits[0].instance_id == 2 and hits[0].caption == "a soft double bed"
    assert [h.score for h in hits] == sorted((h.score for h in hits), reverse=True)
    assert len(hits) == 5 and all(h.terms == ("caption",) and h.visual_score is None for h in hits)  # no labels


def test_name_queries_find_their_instance(encoder):
    book = make_book(encoder, CAPTIONS)
    assert score_instances("a lamp", book, encoder)[0].instance_id == 3
    assert score_instances("something to drink coffee from", book, encoder)[0].instance_id == 4


def test_visual_term_is_weighted_when_available(encoder):
    image = OneHotImageEncoder(["chair", "bed"])
    book = make_book(encoder, {1: "a wooden chair", 2: "a wooden chair"}, visual={2: image.encode_texts(["bed"])[0]})
    hits = score_instances("bed", book, encoder, image_encoder=image)
    assert hits[0].instance_id == 2 and hits[0].terms == ("visual", "caption")
    assert hits[0].score == pytest.approx(0.8 * hits[0].visual_score + 0.2 * hits[0].caption_score)
    assert hits[1].terms == ("caption",)  # no visual feature: caption only


def test_blank_query_is_refused(encoder):
    with pytest.raises(ValueError, match="query is empty"):
        score_instances("   ", make_book(encoder, CAPTIONS), encoder)


# --- openmulti query ----------------------------------------------------------------------------

def box_at(x: float, y: float, size=(1.0, 1.0, 0.8)) -> trimesh.Trimesh:
    box = trimesh.creation.box(size)
    box.apply_translation((x, y, size[2] / 2))
    return box


def write_run(root, encoder):
    """A run directory by hand: per-agent meshes with vertex ids and code books."""
    bed, chair = box_at(1.0, 1.0, (2.0, 1.6, 0.5)), box_at(4.0, 1.0)
    floor = trimesh.creation.box((6.0, 3.0, 0.02))
    floor.apply_translation((3.0, 1.5, -0.01))
    parts = [(floor, 1), (bed, 2), (chair, 3)]
    mesh = trimesh.util.concatenate([m for m, _ in parts])
    ids = np.concatenate([np.full(len(m.vertices), i) for m, i in parts])
    export_scene_mesh(root / "meshes" / "agent_0.ply", mesh, ids)
    (root / "metrics.json").write_text(json.dumps({"config": {"scene": "fake", "agents": 2, "seed": 0}}))
    captions = {1: "the oak floor", 2: "a soft double bed", 3: "a wooden chair"}
    make_book(encoder, captions).save(root / "codebook", "agent_0")
    book1 = make_book(encoder, {1: "a wooden chair"})  # agent_1 saw only the chair (its local id 1)
    book1[1].label = "chair"
    export_scene_mesh(root / "meshes" / "agent_1.ply", chair, np.full(len(chair.vertices), 1))
    book1.save(root / "codebook", "agent_1")
    return root


def test_query_cli_prints_json_and_draws_the_winner(encoder, tmp_path, capsys):
    run = write_run(tmp_path / "run", encoder)
    assert main(["query", "--run", str(run), "--top", "3", "--plot", "the bed"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["query"] == "the bed" and len(out["results"]) == 3
    best = out["results"][0]
    assert (best["id"], best["agent"], best["caption"], best["category"]) == (2, "agent_0", "a soft double bed", "bed")
    assert {r["agent"] for r in out["results"]} <= {"agent_0", "agent_1"}
    png = run / "plots" / "query_the_bed.png"
    assert out["plot"] == str(png) and png.stat().st_size > 5_000


def test_query_cli_errors_exit_2_with_a_clear_message(encoder, tmp_path, capsys):
    assert main(["query", "--run", str(tmp_path / "nowhere"), "a bed"]) == 2
    assert "run directory not found" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["query", "--run", str(tmp_path / "empty"), "a bed"]) == 2
    assert "no code book" in capsys.readouterr().err
    run = write_run(tmp_path / "run", encoder)
    assert main(["query", "--run", str(run), "  "]) == 2
    assert "query text is empty" in capsys.readouterr().err


def test_query_slug():
    assert query_slug("Somewhere to sleep?") == "somewhere_to_sleep"
    assert query_slug("???") == "query"


def test_query_cli_answers_a_file_of_queries_and_refuses_another_encoder(encoder, tmp_path, capsys):
    run = write_run(tmp_path / "run", encoder)
    queries = tmp_path / "queries.txt"
    queries.write_text("# everyday queries\nsomewhere to sleep\n\nsomething to sit on\n")
    assert main(["query", "--run", str(run), "--top", "1", "--queries", str(queries)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [o["query"] for o in out] == ["somewhere to sleep", "something to sit on"]
    assert [o["results"][0]["category"] for o in out] == ["bed", "chair"]
    other = "minilm" if encoder.name == "mpnet" else "mpnet"
    assert main(["query", "--run", str(run), "--text-encoder", other, "a bed"]) == 2
    assert f"made by the {encoder.name!r} text encoder" in capsys.readouterr().err
