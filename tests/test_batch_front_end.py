"""The batch alignment's simulated front end end to end on the tiny world: perceive, align, score semantics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mapping.evaluate.semantic import score_semantics
from mapping.perception.errors import SegmentationErrorConfig
from openmulti_env.world.semantics import category_vocabulary, semantic_ground_truth
from studies.batch_alignment import align_team, labelled_points
from studies.batch_alignment.front_end import FrontEndConfig, perceive_team


@pytest.fixture(scope="module")
def perfect(tiny_world):
    return perceive_team(tiny_world, seed=0, config=FrontEndConfig(errors=SegmentationErrorConfig.none()),
                         progress=False)


def test_every_agent_perceives_and_fuses_its_frames(perfect, tiny_world):
    assert set(perfect.fused) == {"agent_0", "agent_1"}
    for name, fused in perfect.fused.items():
        assert len(perfect.frames[name]) == len(perfect.segmentations[name]) == len(tiny_world.agent_poses[0])
        assert fused.instances and all(inst.points.shape[1] == 3 for inst in fused.instances.values())


def test_labelled_points_lie_on_the_ground_truth_and_carry_code_book_ids(perfect, tiny_world):
    result = align_team(perfect, "paper")
    points, ids = labelled_points(perfect, result, "agent_0")
    assert len(points) == len(ids) > 1000
    assert set(np.unique(ids)) <= set(result.codebook)
    gt_points, _ = semantic_ground_truth(tiny_world, 50_000, seed=0)
    distance, _ = cKDTree(gt_points).query(points)
    assert np.median(distance) < 0.02


def test_perfect_masks_with_oracle_ids_score_high_and_alignment_modes_agree(perfect, tiny_world):
    gt_points, gt_labels = semantic_ground_truth(tiny_world, 50_000, seed=0)
    vocabulary = category_vocabulary(tiny_world)
    scores = {}
    for mode in ("none", "paper", "oracle"):
        result = align_team(perfect, mode)
        pts, ids = zip(*(labelled_points(perfect, result, a) for a in perfect.frames))
        scores[mode] = score_semantics(gt_points, gt_labels, np.concatenate(pts), np.concatenate(ids),
                                       result.codebook, vocabulary).f_miou
    assert scores["oracle"] > 80.0
    assert abs(scores["paper"] - scores["oracle"]) < 5.0  # nothing to repair with perfect masks
    with pytest.raises(ValueError, match="unknown alignment"):
        align_team(perfect, "psychic")
