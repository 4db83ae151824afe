"""The front reward: bytes priced by the episode's fixed-rate front, so a return is the margin over that front."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from openmulti_env.environment.reward_front import FrontPoints, front, front_points, schedule_plan
from openmulti_env.environment.rewards import BaselineEpisodes, step_rewards


def test_the_front_keeps_points_that_complete_more_than_every_cheaper_one_and_is_flat_past_the_last():
    points = [(0.0, 0.2), (4.0, 0.5), (2.0, 0.6), (6.0, 0.55), (8.0, 0.9), (8.0, 0.7)]
    assert front_points(points) == [(0.0, 0.2), (2.0, 0.6), (8.0, 0.9)]
    f = front(points)
    assert f(1.0) == pytest.approx(0.4)  # half way from (0, 0.2) to (2, 0.6)
    assert f(5.0) == pytest.approx(0.75)
    assert f(20.0) == pytest.approx(0.9)
    with pytest.raises(ValueError, match="at least one"):
        front([])


def test_fixed_schedules_send_on_their_rounds_and_at_their_rate():
    rng = np.random.default_rng(0)
    sent = [bool(schedule_plan("every:3", 3, r, rng).send_params.any()) for r in range(7)]
    assert sent == [True, False, False, True, False, False, True]
    assert not schedule_plan("rate:0", 3, 0, rng).send_params.any()
    full = schedule_plan("rate:1", 3, 0, rng)
    np.testing.assert_array_equal(full.send_params, ~np.eye(3, dtype=bool))
    np.testing.assert_array_equal(full.share_rays, ~np.eye(3, dtype=bool))
    draws = np.mean([schedule_plan("rate:0.25", 4, r, rng).send_params.sum() / 12 for r in range(400)])
    assert draws == pytest.approx(0.25, abs=0.02)
    for bad in ("every:0", "rate:1.5", "sometimes", "every:x"):
        with pytest.raises(ValueError, match="unknown fixed schedule"):
            schedule_plan(bad, 3, 0, rng)


def test_a_return_is_the_margin_over_the_front_at_the_team_s_bytes_over_what_talking_adds():
    settings = SimpleNamespace(reward="team", reward_baseline="front", budget_penalty=0.05)
    never = np.array([[0, 0], [0.10, 0.20], [0.20, 0.30]])
    always = np.array([[0, 0], [0.20, 0.30], [0.60, 0.70]])
    base = BaselineEpisodes(never, always, np.array([3.0, 1.0]))
    points = FrontPoints(("never", "every:2", "always"), np.array([0.0, 2.0, 4.0]), np.array([0.25, 0.55, 0.65]))
    span = 0.65 - 0.25

    def episode_return(completions: np.ndarray, mb_per_step: list[np.ndarray]) -> float:
        total, sent = 0.0, 0.0
        for t in (1, 2):
            gains = completions[t] - completions[t - 1]
            total += step_rewards(settings, gains, mb_per_step[t - 1], np.zeros(2), t, base, points, sent)[0]
            sent += float(mb_per_step[t - 1].sum())
        return total

    zero = np.zeros(2)
    assert episode_return(never, [zero, zero]) == pytest.approx(0.0, abs=1e-12)
    assert episode_return(always, [np.array([1.5, 0.5]), np.array([1.5, 0.5])]) == pytest.approx(0.0, abs=1e-12)
    # 3 MB in the first step, nothing after, and a final completion of 0.62: the front gives 0.60 at 3 MB
    above = np.array([[0, 0], [0.30, 0.40], [0.58, 0.66]])
    assert episode_return(above, [np.array([2.0, 1.0]), zero]) == pytest.approx((0.62 - 0.60) / span)
    # the same bytes sent in the last step instead: the same return (the price telescopes to F(total MB))
    assert episode_return(above, [zero, np.array([2.0, 1.0])]) == pytest.approx((0.62 - 0.60) / span)
    with pytest.raises(RuntimeError, match="front"):
        step_rewards(settings, zero, zero, zero, 1, base, None, 0.0)
    with pytest.raises(RuntimeError, match="team reward"):
        step_rewards(SimpleNamespace(**{**vars(settings), "reward": "individual"}), zero, zero, zero, 1, base, points)


def test_the_env_plays_the_front_once_and_pays_0_on_it_and_less_under_it(tmp_path):
    from openmulti_env import parallel_env

    kwargs = dict(preset="rl_tiny", num_agents=2, cache_dir=str(tmp_path / "cache"), reward_baseline="front")
    env = parallel_env(seed=1, **kwargs)
    returns = {}
    for name, sends in (("always", lambda r: 1), ("never", lambda r: 0), ("every:2", lambda r: int(r % 2 == 0))):
        env.reset(seed=7)
        total, r = 0.0, 0
        while env.agents:
            _, rewards, *_ = env.step({a: np.full(2, sends(r), np.int8) for a in env.agents})
            total, r = total + rewards["agent_0"], r + 1
        returns[name] = total
    front_here = env._rewarder.front
    assert env._rewarder.baselines.played == 10  # never, always and the eight schedules of the front, once
    env.close()
    assert front_here.schedules[0] == "never" and front_here.schedules[-1] == "always"
    assert returns["never"] == pytest.approx(0.0, abs=1e-9)
    kept = front_points(list(zip(front_here.mb, front_here.completion)))
    assert returns["always"] == pytest.approx(0.0, abs=1e-9) if kept[-1][0] == front_here.mb[-1] else returns["always"] < 0
    every_2 = front_here.schedules.index("every:2")
    on_front = (front_here.mb[every_2], front_here.completion[every_2]) in kept
    assert returns["every:2"] == pytest.approx(0.0, abs=1e-9) if on_front else returns["every:2"] < 0
    again = parallel_env(seed=1, **kwargs)
    again.reset(seed=7)
    assert again._rewarder.baselines.played == 0  # both records read from the disk cache
    again.close()
    with pytest.raises(ValueError, match="needs env.reward='team'"):
        parallel_env(preset="rl_tiny", reward_baseline="front", reward="individual")


def test_a_torn_or_foreign_cache_record_is_played_again_not_read(tmp_path):
    from openmulti_env.environment.rewards import read_record

    path = tmp_path / "front.json"
    for text in ("null", "[1, 2]", "{\"format\": 1, \"schedules\": [\"every:2\"], \"mb\": [1.0, 2.0], \"completion\": [0.5]}",
                 "{\"format\": 1, \"sched", "{\"format\": 0}"):
        path.write_text(text)
        assert read_record(path, FrontPoints.from_record) is None, text
    good = FrontPoints(("every:2",), np.array([1.0]), np.array([0.5]))
    path.write_text(__import__("json").dumps(good.as_record()))
    assert read_record(path, FrontPoints.from_record).schedules == ("every:2",)
