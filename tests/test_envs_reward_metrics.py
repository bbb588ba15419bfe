"""Reward terms and metrics on hand-worked steps and episodes (no scene needed)."""

from dataclasses import asdict, replace

import pytest

from vid2sim.envs.config import RewardConfig
from vid2sim.envs.metrics import outcome as episode_outcome
from vid2sim.envs.metrics import PINNED, EpisodeRecord, outcomes, sns, sns_proximity, spl, summarize
from vid2sim.envs.reward import StepOutcome, reward

C = RewardConfig()


def outcome(**kw) -> StepOutcome:
    base = dict(prev_distance=10.0, distance=9.8, steer_change=0.0, speed=1.0, collided=False,
                collision_events=0, on_walkable=True, step=1)
    base.update(kw)
    return StepOutcome(**base)


def test_running_step_terms():
    # moved 0.2 m closer, steering changed by 0.5 at full speed, in contact
    t = reward(outcome(steer_change=0.5, collided=True, collision_events=1), C)
    assert t.end == "" and not t.terminated and not t.truncated
    assert t.distance == pytest.approx(0.2)
    assert t.steer == pytest.approx(-0.05 * 0.5 * 1.0)
    assert t.crash == -1.0 and t.time == -0.1 and t.terminal == 0.0
    assert t.total == pytest.approx(0.2 - 0.025 - 1.0 - 0.1)


def test_moving_away_is_penalised_and_steer_scales_with_speed():
    t = reward(outcome(distance=10.3, steer_change=2.0, speed=0.5), C)
    assert t.distance == pytest.approx(-0.3) and t.steer == pytest.approx(-0.05)


def test_success_failure_and_timeout():
    s = reward(outcome(distance=0.49), C)
    assert s.end == "success" and s.terminal == 10.0 and s.terminated
    off = reward(outcome(on_walkable=False), C)
    assert off.end == "left_walkable" and off.terminal == -10.0 and off.terminated
    assert reward(outcome(collision_events=3, collided=True), C).end == ""  # 3 is allowed
    many = reward(outcome(collision_events=4, collided=True), C)
    assert many.end == "collisions" and many.terminal == -10.0 and many.crash == -1.0
    late = reward(outcome(step=3000), C)
    assert late.truncated and not late.terminated and late.terminal == -10.0
    assert reward(outcome(step=2999), C).end == ""


def ep(success, shortest, travelled, events=0, coll_steps=0, prox=0, steps=100):
    return EpisodeRecord(success, shortest, travelled, events, coll_steps, prox, steps)


def test_spl_batra():
    assert spl(ep(True, 10.0, 12.5)) == pytest.approx(0.8)  # 10 / max(12.5, 10)
    assert spl(ep(True, 10.0, 9.6)) == pytest.approx(1.0)  # stopped inside the success radius
    assert spl(ep(False, 10.0, 10.0)) == 0.0
    # the official code's "SPL" (collision rate x success) would give 0 here: ours does not
    assert spl(ep(True, 10.0, 20.0, events=0)) == pytest.approx(0.5)


def test_sns_released_and_proximity():
    e = ep(True, 10.0, 11.0, events=2, coll_steps=5, prox=15, steps=50)
    assert sns(e) == pytest.approx(0.9)  # 1 - 5/50
    assert sns_proximity(e) == pytest.approx(0.6)  # 1 - (5 + 15)/50


def test_summary_hand_worked():
    records = [ep(True, 10.0, 12.5, events=1, coll_steps=2, steps=100),
               ep(False, 20.0, 5.0, events=4, coll_steps=10, prox=10, steps=50),
               ep(True, 8.0, 8.0, steps=40)]
    s = summarize(records)
    assert s.episodes == 3
    assert s.sr == pytest.approx(2 / 3)
    assert s.spl == pytest.approx((0.8 + 0.0 + 1.0) / 3)
    assert s.cost == pytest.approx(5 / 3)
    assert s.sns == pytest.approx((0.98 + 0.8 + 1.0) / 3)
    assert s.sns_proximity == pytest.approx((0.98 + 0.6 + 1.0) / 3)


def test_outcomes_split_time_outs_into_pinned_and_free():
    pinned = replace(ep(False, 10.0, 1.0, events=1, coll_steps=300, steps=600), end="timeout")
    free = replace(ep(False, 10.0, 30.0, events=2, coll_steps=299, steps=600), end="timeout")
    off = replace(ep(False, 10.0, 4.0, steps=40), end="left_walkable")
    records = [ep(True, 10.0, 11.0), pinned, pinned, free, off]
    assert [episode_outcome(e) for e in records] == ["success", PINNED, PINNED, "timeout", "left_walkable"]
    assert outcomes(records) == {PINNED: 2, "success": 1, "timeout": 1, "left_walkable": 1}
    row = {"scene_id": "s", **asdict(pinned), "a_later_field": 1}  # a saved report's row
    assert EpisodeRecord.from_row(row) == pinned
