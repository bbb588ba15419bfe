"""Training-only wrappers (stuck termination, expert warm-up), the `nav_episode` info key, `eval --record`."""

from __future__ import annotations

import json

import cv2
import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.monitor import Monitor
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.envs.metrics import EpisodeRecord, outcomes
from vid2sim.envs.physics import RobotState
from vid2sim.formats.episode_trace import read_trace
from vid2sim.training.config import SACConfig, TrainConfig
from vid2sim.training.privileged import PRIVILEGED_ID
from vid2sim.training.sac import train
from vid2sim.training.wrappers import STUCK, StuckTermination

SCENE = "synthetic-street-s1"


@pytest.fixture(scope="module")
def street_registry(tmp_path_factory):
    from benchmarks.street_registry import build
    return build(tmp_path_factory.mktemp("streets"), [1, 2]).root


def face_nearest_wall(env: gym.Env, seed: int) -> None:
    """Reset, then turn the robot (in place, by teleport) towards the closest mesh ray hit."""
    env.reset(seed=seed)
    u = env.unwrapped
    mesh, _ = u.ranges()
    assert mesh.min() < u.max_range  # the street has a wall within range
    yaw = u.state.yaw + u.angles[int(np.argmin(mesh))]
    u.state = RobotState(u.state.x, u.state.y, yaw)
    u.world.physics.place(u.state.x, u.state.y, yaw)


def drive(env: gym.Env, steps: int) -> tuple[list[float], bool, dict]:
    rewards, info = [], {}
    for _ in range(steps):
        _, r, terminated, truncated, info = env.step(np.array([1.0, 0.0], np.float32))
        rewards.append(r)
        if terminated or truncated:
            return rewards, True, info
    return rewards, False, info


def test_pressing_into_a_wall_is_stuck_and_the_wrapper_ends_it(street_registry, tmp_path):
    make = dict(registry=str(street_registry), scenes=SCENE, training=False, checkout_root=str(tmp_path))
    plain = gym.make(PRIVILEGED_ID, **make)
    face_nearest_wall(plain, seed=0)
    rewards, ended, info = drive(plain, 25)
    assert not ended and info["collided"]  # blocked for good: no reverse, blocked moves are undone
    assert rewards[-1] == pytest.approx(-1.1)  # crash + time penalty every step
    assert info["collision_events"] == 1

    env = StuckTermination(gym.make(PRIVILEGED_ID, **make), steps=5)
    face_nearest_wall(env, seed=0)
    rewards, ended, info = drive(env, 25)
    assert ended and info["end"] == STUCK
    assert rewards[-1] == pytest.approx(-1.1 - 10.0)  # the paper's failure reward on top
    rec = info["nav_episode"]
    assert isinstance(rec, EpisodeRecord) and rec.end == STUCK and not rec.success
    assert len(rewards) < 15 and rec.steps == len(rewards)


def test_standing_still_is_stuck_too(street_registry, tmp_path):
    env = StuckTermination(gym.make(PRIVILEGED_ID, registry=str(street_registry), scenes=SCENE, training=False,
                                    checkout_root=str(tmp_path)), steps=6)
    env.reset(seed=1)
    for k in range(1, 10):
        *_, terminated, truncated, info = env.step(np.array([-0.5, 0.3], np.float32))  # speed <= 0: stop
        if terminated or truncated:
            break
    assert k == 6 and terminated and info["end"] == STUCK and not info["collided"]


def test_nav_episode_key_leaves_episode_to_sb3_monitor(street_registry, tmp_path):
    env = Monitor(gym.make(PRIVILEGED_ID, registry=str(street_registry), scenes=SCENE, training=False,
                           checkout_root=str(tmp_path), max_steps=5))
    env.reset(seed=0)
    for _ in range(5):
        *_, terminated, truncated, info = env.step(np.array([0.0, 0.0], np.float32))
        if terminated or truncated:
            break
    assert truncated and set(info["episode"]) == {"r", "l", "t"} and info["episode"]["l"] == 5
    assert info["nav_episode"].end == "timeout"


@pytest.mark.slow
def test_eval_record_writes_one_mp4_per_recorded_trial(street_registry, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the CLI checks scenes out under ./vid2sim-checkouts
    out = tmp_path / "videos"
    res = CliRunner().invoke(app, ["eval", "policy", "--policy", "expert", "--registry", str(street_registry),
                                   "--scenes", SCENE, "--trials", "2", "--record", "1", "--record-dir", str(out),
                                   "--privileged", "--out", str(tmp_path / "report.json")])
    assert res.exit_code == 0, res.output
    report = json.loads((tmp_path / "report.json").read_text())
    ends = outcomes([EpisodeRecord.from_row(r) for r in report["records"]])  # from the saved records
    assert sum(ends.values()) == 2  # how the two episodes ended, printed below the metrics:
    assert "outcomes: " + ", ".join(f"{k} {n}" for k, n in ends.items()) in res.output
    # the video, and beside it the episode's trace (poses, contacts, what the map shows)
    assert sorted(p.name for p in out.iterdir()) == [f"{SCENE}-trial0.mp4", f"{SCENE}-trial0.trace.json"]
    assert report["videos"] == [str(out / f"{SCENE}-trial0.mp4")]
    cap = cv2.VideoCapture(str(out / f"{SCENE}-trial0.mp4"))
    frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    ok, frame = cap.read()
    cap.release()
    assert ok and frames == report["records"][0]["steps"] + 1  # the reset frame + one per step
    assert frame.std() > 5  # the camera view and the map, not a blank frame
    trace = read_trace(out / f"{SCENE}-trial0.trace.json")
    assert trace.scene_id == SCENE and trace.steps == frames  # a pose per frame: the reset one + one per step


@pytest.mark.parametrize("warmup,bc_weight,ent", [("expert", 0.0, "auto"), ("random", 0.0, "auto"),
                                                  ("expert", 1.0, "auto"), ("expert", 1.0, "0.05")])
def test_expert_warmup_fills_the_replay_buffer_with_demonstrations(street_registry, tmp_path, warmup, bc_weight,
                                                                   ent):
    run = tmp_path / f"{warmup}{bc_weight}{ent}"
    sac = SACConfig(learning_starts=80, batch_size=16, buffer_size=200, net_arch=(16, 16), use_sde=False,
                    warmup=warmup, bc_weight=bc_weight, ent_coef=ent)
    total = 100 if bc_weight else 80  # with BC: 20 steps of SAC + BC updates after the warm-up
    config = TrainConfig(run_dir=str(run), total_steps=total, env_id=PRIVILEGED_ID,
                         env_module="vid2sim.training.privileged", registry=str(street_registry),
                         scene_ids=[SCENE], env_kwargs={"training": True}, n_envs=2, n_actors=0,
                         stuck_steps=10, save_replay_buffer=True, checkpoint_every=total, sac=sac)
    result = train(config, progress_bar=False, log_every=40)
    assert result.num_timesteps == total
    model = SAC.load(run / "final.zip", device="cpu")
    model.load_replay_buffer(run / "checkpoints" / "replay.pkl")
    warm = 80 // config.n_envs  # buffer rows written during the warm-up
    actions = model.replay_buffer.actions[:warm].reshape(-1, 2)  # [80, 2]
    rewards = model.replay_buffer.rewards[:warm].ravel()
    if warmup == "expert":  # pure pursuit: speed in [0.3, 1], drives towards the goal
        assert actions[:, 0].min() >= 0.3 - 1e-6 and rewards.mean() > 0
    else:  # uniform random: half the speed commands are below zero (standing still)
        assert actions[:, 0].min() < 0 and rewards.mean() < 0


def test_bc_pretraining_fits_the_actor_to_the_demonstrations(street_registry, tmp_path):
    def run(pretrain: int) -> tuple[SAC, float]:
        sac = SACConfig(learning_starts=60, batch_size=16, buffer_size=200, net_arch=(16, 16), use_sde=False,
                        warmup="expert", bc_weight=1.0, bc_pretrain_steps=pretrain, learning_rate=3e-3)
        config = TrainConfig(run_dir=str(tmp_path / f"p{pretrain}"), total_steps=64, env_id=PRIVILEGED_ID,
                             env_module="vid2sim.training.privileged", registry=str(street_registry),
                             scene_ids=[SCENE], env_kwargs={"training": True}, n_envs=2, n_actors=0,
                             stuck_steps=10, save_replay_buffer=True, checkpoint_every=64, sac=sac)
        train(config, progress_bar=False, log_every=32)
        model = SAC.load(tmp_path / f"p{pretrain}" / "final.zip", device="cpu")
        model.load_replay_buffer(tmp_path / f"p{pretrain}" / "checkpoints" / "replay.pkl")
        buf = model.replay_buffer
        obs, demos = buf.observations[:30].reshape(60, -1), buf.actions[:30].reshape(60, 2)  # warm-up rows
        pred = model.predict(obs, deterministic=True)[0]  # [60, 2]
        return model, float(np.mean((pred - demos) ** 2))

    (fresh, mse_fresh), (pre, mse_pre) = run(0), run(300)
    assert pre.pretrained and not fresh.pretrained
    assert pre._n_updates >= 300 > fresh._n_updates
    assert mse_pre < 0.5 * mse_fresh  # the actor imitates the expert before SAC's first own action


def test_teacher_clearance_reads_the_view_left_to_right(street_registry, tmp_path):
    """K rays over the camera's field of view, left to right: turning left by one ray spacing moves
    every reading one column to the right; a wall is within range in some heading."""
    from vid2sim.envs.sensing import camera_hfov_deg
    from vid2sim.training.wrappers import CLEARANCE_RANGE, TeacherLabels
    env = TeacherLabels(gym.make("vid2sim/PointNav-v0", registry=str(street_registry), scenes=SCENE,
                                 training=False, fidelity="exact", checkout_root=str(tmp_path)), clearance_rays=9)
    _, info = env.reset(seed=0)
    first = info["teacher_clearance"]
    assert first.shape == (9,) and first.dtype == np.float32 and ((first > 0) & (first <= 1)).all()
    u = env.unwrapped
    step = np.radians(camera_hfov_deg(u.config.camera.width, u.config.camera.focal)) / 8
    x, y, yaw = u.state.x, u.state.y, u.state.yaw
    views = []
    for turn in (0.0, step, np.pi / 2, np.pi, 1.5 * np.pi):
        u.state = RobotState(x, y, yaw + turn)
        views.append(env.clearance())
    np.testing.assert_allclose(views[0], first)
    np.testing.assert_allclose(views[1][1:], views[0][:-1], atol=0.1 / CLEARANCE_RANGE)  # one march step
    assert min(v.min() for v in views) < 0.9  # a facade or the kerb within 4.5 m in some heading
    with pytest.raises(ValueError, match="clearance_rays"):
        TeacherLabels(env.env, clearance_rays=-1)
    env.close()


def teacher_after_drift(registry, checkouts, replan: float, drift_steps: int = 12, lookahead: float = 1.0):
    """(label after driving a left drift from seed 0's start, label of a fresh teacher put at that pose)."""
    from vid2sim.training.wrappers import TeacherLabels

    def make():
        return TeacherLabels(gym.make("vid2sim/PointNav-v0", registry=str(registry), scenes=SCENE, training=False,
                                      fidelity="exact", checkout_root=str(checkouts)), replan_distance=replan,
                             lookahead=lookahead)
    driven, fresh = make(), make()
    driven.reset(seed=0)
    for _ in range(drift_steps):
        _, _, terminated, truncated, info = driven.step(np.array([1.0, 0.4], np.float32))
        assert not (terminated or truncated)
    fresh.reset(seed=0)
    s = driven.unwrapped.state
    fresh.unwrapped.state = RobotState(s.x, s.y, s.yaw)
    fresh.unwrapped.world.physics.place(s.x, s.y, s.yaw)
    fresh.expert.last = None  # no memory of its own start
    label = fresh._label({})["teacher_action"]
    driven.close()
    fresh.close()
    return info["teacher_action"], label


def test_teacher_replanning_at_every_state_labels_the_state_alone(street_registry, tmp_path):
    """replan_distance 0: a teacher that drove here and one put here label the state alike, and the
    label (the way from here) differs from the default teacher's, which steers back to the route it
    planned at the start while the robot is within 0.3 m of it."""
    from vid2sim.training.wrappers import TeacherLabels
    driven, fresh = teacher_after_drift(street_registry, tmp_path, 0.0, drift_steps=4)
    np.testing.assert_allclose(driven, fresh, atol=1e-6)
    default, _ = teacher_after_drift(street_registry, tmp_path, 0.3, drift_steps=4)
    assert abs(default[1] - driven[1]) > 0.05
    env = gym.make("vid2sim/PointNav-v0", registry=str(street_registry), scenes=SCENE, checkout_root=str(tmp_path))
    with pytest.raises(ValueError, match="replan_distance"):
        TeacherLabels(env, replan_distance=-1.0)
    env.close()


def test_teacher_with_a_longer_lookahead_steers_back_more_gently(street_registry, tmp_path):
    """Off the route after a left drift, a teacher aiming 2 m ahead steers back the same way as the
    default one (1 m) with less lock: pure pursuit's gain falls with the look-ahead distance."""
    from vid2sim.ranges import RangeError
    from vid2sim.training.wrappers import TeacherLabels
    near, _ = teacher_after_drift(street_registry, tmp_path, 0.3, drift_steps=10)
    far, _ = teacher_after_drift(street_registry, tmp_path, 0.3, drift_steps=10, lookahead=2.0)
    assert near[1] < -0.3 and far[1] < 0  # both steer right, back to the route
    assert abs(far[1]) < 0.8 * abs(near[1])
    env = gym.make("vid2sim/PointNav-v0", registry=str(street_registry), scenes=SCENE, checkout_root=str(tmp_path))
    with pytest.raises(RangeError, match="lookahead"):
        TeacherLabels(env, lookahead=0.0)
    env.close()
