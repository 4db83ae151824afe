"""The fixed-rate fronts the schedule studies read: the concave envelope, the Pareto front's margins per cell
and their report."""

import numpy as np
import pytest

from openmulti_env.environment.reward_front import FRONT_SCHEDULES
from studies.fronts import FIXED_RATE, cell_margins, concave_front_at, is_fixed_rate, margins, mean_se


def test_the_fixed_rate_family_runs_from_never_to_always():
    assert FIXED_RATE[0] == "never" and FIXED_RATE[-1] == "always" and FIXED_RATE[1:-1] == FRONT_SCHEDULES
    assert all(is_fixed_rate(p) for p in FIXED_RATE)
    assert not any(is_fixed_rate(p) for p in ("novelty", "instance_novelty", "runs/a/best.json", "at:11"))


def test_the_concave_front_is_the_upper_envelope_read_at_equal_bytes():
    points = [(0.0, 10.0), (40.0, 50.0), (60.0, 40.0), (100.0, 60.0), (50.0, 52.0)]
    assert concave_front_at(points, 0.0) == pytest.approx(10.0)
    assert concave_front_at(points, 20.0) == pytest.approx(30.0)  # between never and every:3-like
    assert concave_front_at(points, 60.0) > 52.0  # the dominated (60, 40) is not on the front
    assert concave_front_at(points, 100.0) == pytest.approx(60.0)
    assert concave_front_at(points, 500.0) == pytest.approx(60.0)  # flat past the last point


def test_a_margin_is_read_on_the_pareto_front_at_the_policys_bytes():
    # the front: (0, 50), (20, 60), (40, 61); (30, 55) is under it and (20, 60) is not mixed away
    rows = [{"cell": "c:1", "policy": p, "mb": mb, "completion": c}
            for p, mb, c in (("never", 0.0, 50.0), ("every:2", 20.0, 60.0), ("rate:0.5", 30.0, 55.0),
                             ("always", 40.0, 61.0), ("A", 10.0, 58.0))]
    family = ("never", "every:2", "rate:0.5", "always")
    assert cell_margins(rows, "A", family) == pytest.approx({"c:1": 3.0})  # front at 10 MB: 55
    assert cell_margins(rows, "A", family + ("every:4",)) == {}  # a cell lacking a schedule is left out
    assert margins(rows, "B", family).size == 0


def test_mean_se_marks_a_mean_beyond_two_standard_errors():
    assert mean_se(np.array([3.0, 3.5, 2.5, 3.2])).endswith("**> 2 SE**")
    assert mean_se(np.array([-3.0, -3.5, -2.5, -3.2])).endswith("< -2 SE")
    assert mean_se(np.array([1.0, -1.0, 0.5, -0.5])) == "+0.00 ± 0.46"
