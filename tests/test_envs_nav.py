"""NavEnv on a real scene: the synthetic street's ground-truth bundle in a tmp registry.

Covers the env checkers (gymnasium + SB3) per task and variant, seeding, bad actions, the
collision mesh stopping the robot, the map-size refusal and the scripted expert.
"""

from __future__ import annotations

import math

import gymnasium
import numpy as np
import pytest
import open3d as o3d
import torch
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import vid2sim.envs  # noqa: F401  (registers the env ids)
from tests.street_bundles import renamed_copy, street_bundle
from vid2sim.envs import simready
from vid2sim.envs.config import FastRenderConfig, RobotConfig
from vid2sim.envs.expert import ExpertConfig, PurePursuitExpert, _arc_on_map, _safe_steer
from vid2sim.envs.nav_env import InvalidActionError, NavEnv
from vid2sim.envs.physics import PhysicsWorld, RobotState
from vid2sim.envs.scenes import SceneError, load_scene
from vid2sim.registry import Registry

SCENE = "synthetic-street-s11"


@pytest.fixture(scope="module")
def registry(tmp_path_factory):
    """GT bundle of a 1 s synthetic street (20k splats) + a copy with a tiny walkable map."""
    root = tmp_path_factory.mktemp("envs")
    bundle = street_bundle(root)
    reg = Registry(root / "registry")
    reg.add(bundle)
    reg.add(_tiny_copy(bundle, root / "tiny"))
    return reg, root / "checkouts"


def _tiny_copy(bundle, out):
    renamed_copy(bundle, out, "tiny-street")
    with np.load(out / "walkable.npz") as z:
        grid, origin, res = z["grid"].copy(), z["origin"], z["resolution"]
    rows, cols = np.nonzero(grid)
    keep = np.zeros_like(grid)
    r0, c0 = rows[len(rows) // 2], cols[len(cols) // 2]
    keep[r0 - 10:r0 + 10, c0 - 30:c0 + 30] = 1  # 3 m x 1 m of walkable ground
    np.savez_compressed(out / "walkable.npz", grid=keep, origin=origin, resolution=res)
    return out


FAST = FastRenderConfig(views=256)  # the default set, measured on fewer views (test time)


def make(registry, task: str = "PointNav", **kw):
    reg, co = registry
    kw.setdefault("fast", FAST)
    return gymnasium.make(f"vid2sim/{task}-v0", registry=reg.root, scenes=SCENE, checkout_root=co, **kw)


@pytest.mark.parametrize("variant,fidelity", [("rgb", "fast"), ("depth", "fast"), ("mesh-rgb", None),
                                              ("rgb", "exact"), ("depth", "exact")])
def test_check_env_pointnav(registry, variant, fidelity):
    env = make(registry, variant=variant, fidelity=fidelity)
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)
    obs, _ = env.reset(seed=0)
    chans = 1 if variant == "depth" else 3
    assert obs["image"].shape == (6, chans, 72, 128) and obs["image"].dtype == np.uint8
    assert obs["vector"].shape == (6, 2) and obs["image"].std() > 5  # a picture, not a blank
    env.close()


def test_check_env_socialnav_with_actors(registry):
    env = make(registry, task="SocialNav")
    gym_check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)
    env.reset(seed=2)
    s = env.unwrapped.topdown_state()
    assert 1 <= len(s["pedestrians"]) <= 4 and len(s["obstacles"]) <= 5
    before = s["pedestrians"].copy()
    env.step(np.array([0.0, 0.0], np.float32))
    moved = np.linalg.norm(env.unwrapped.topdown_state()["pedestrians"] - before, axis=1)
    assert np.all((moved > 0.1) & (moved < 0.4))  # 1.0-1.6 m/s for 0.2 s
    env.close()


def test_same_seed_same_episode(registry):
    a, b = make(registry), make(registry)
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (8, 2)).astype(np.float32)
    oa, _ = a.reset(seed=7)
    ob, _ = b.reset(seed=7)
    for act in acts:
        for k in oa:
            np.testing.assert_array_equal(oa[k], ob[k])
        oa, ra, *_ = a.step(act)
        ob, rb, *_ = b.step(act)
        assert ra == rb
    oc, _ = a.reset(seed=8)
    assert not np.array_equal(oc["vector"], ob["vector"])  # another seed, another episode


def test_fast_fidelity_defaults_shared_set_and_agreement(registry):
    simready._CACHE.clear()  # made here (another test in this process may have made the same scene's set)
    fast, exact = make(registry, training=False, fidelity="fast"), make(registry, training=False)
    assert make(registry).unwrapped.config.render_fidelity == "fast"  # training default
    assert exact.unwrapped.config.render_fidelity == "exact"  # evaluation default
    other = make(registry, training=False, fidelity="fast", variant="depth")
    sim = fast.unwrapped.world.view.sim
    assert other.unwrapped.world.view.sim is sim  # one sim-ready set per scene and process
    assert 0 < sim.model.num < exact.unwrapped.world.assets.splats.num
    of, _ = fast.reset(seed=4)
    oe, _ = exact.reset(seed=4)
    np.testing.assert_array_equal(of["vector"], oe["vector"])  # same episode
    a, b = of["image"][-1].astype(float), oe["image"][-1].astype(float)
    psnr = 10 * np.log10(255.0 ** 2 / ((a - b) ** 2).mean())
    assert 20.0 < psnr < 80.0, psnr  # close to the exact render, not the same image
    with pytest.raises(ValueError, match="fidelity"):
        make(registry, fidelity="approx")
    cached = list((registry[1] / "simready").glob("simready-*.ply"))  # kept beside the checkouts
    assert len(cached) == 1
    simready._CACHE.clear()  # a new process: the set is read back from disk, not made again
    again = make(registry, training=False, fidelity="fast")
    again.reset(seed=4)
    torch.testing.assert_close(again.unwrapped.world.view.sim.model.means, sim.model.means)


def test_exact_view_draws_through_the_frame_kernel_bit_for_bit(registry):
    """The exact env view renders through SceneBatch; the pixels equal StaticScene.render's."""
    from vid2sim.envs.rendering import view_outputs
    from vid2sim.envs.camera import splat_camera

    env = make(registry, training=False)
    env.reset(seed=5)
    view = env.unwrapped.world.view
    assert view.batch is not None
    for step in range(3):
        env.step(np.array([1.0, 0.3], np.float32))
        w2c = env.unwrapped.last_world_to_cam
        rgb, depth = view.draw(w2c)
        out = view.scene.render(splat_camera(view.conf, w2c), view.settings)
        ref_rgb, ref_depth = view_outputs(out.rgb, out.depth, out.alpha)
        assert rgb.any()
        assert np.array_equal(rgb, ref_rgb)
        assert np.array_equal(depth, ref_depth)


def test_sweep_check_same_as_substep_queries(registry):
    """One contact query per clear control step gives the substep loop's episode exactly."""
    fast, ref = make(registry), make(registry, sweep_check=False)
    rng = np.random.default_rng(1)
    clear = collided = 0
    for seed in range(3):
        fast.reset(seed=seed)
        ref.reset(seed=seed)
        for _ in range(40):
            act = np.array([1.0, rng.choice([-1.0, 0.0, 1.0])], np.float32)
            of, rf, tf, uf, inf = fast.step(act)
            orf, rr, tr, ur, inr = ref.step(act)
            assert fast.unwrapped.robot_pose() == ref.unwrapped.robot_pose()
            assert (rf, tf, uf, inf["collided"]) == (rr, tr, ur, inr["collided"])
            np.testing.assert_array_equal(of["image"], orf["image"])
            assert fast.unwrapped.travelled == ref.unwrapped.travelled
            collided += inf["collided"]
            if tf or uf:
                break
        clear += fast.unwrapped.clear_steps
        assert ref.unwrapped.clear_steps == 0
    assert clear > 0 and collided > 0  # both the skip and the substep loop ran


def test_bad_actions_named_and_harmless(registry):
    env, ref = make(registry), make(registry)
    env.reset(seed=3)
    ref.reset(seed=3)
    for bad in ([np.nan, 0.0], [0.5, np.inf], [1.0]):
        with pytest.raises(InvalidActionError):
            env.step(np.array(bad, np.float32))
    o1, r1, *_ = env.step(np.array([5.0, -7.0], np.float32))  # clipped to (1, -1)
    o2, r2, *_ = ref.step(np.array([1.0, -1.0], np.float32))
    np.testing.assert_array_equal(o1["image"], o2["image"])
    assert r1 == r2


def test_robot_cannot_drive_through_a_mesh_wall(registry):
    reg, co = registry
    assets = load_scene(reg, SCENE, co)
    world = PhysicsWorld(assets.collision, RobotConfig())
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(assets.collision.vertices),
                     o3d.core.Tensor(assets.collision.faces.astype(np.uint32)))
    rows, cols = np.nonzero(assets.walkable.grid)
    x0 = assets.walkable.origin[0] + (cols.mean() + 0.5) * assets.walkable.resolution
    y0 = assets.walkable.origin[1] + (rows.mean() + 0.5) * assets.walkable.resolution
    # the nearest wall along +y or -y at box mid-height
    rays = np.array([[x0, y0, 0.35, 0, 1, 0], [x0, y0, 0.35, 0, -1, 0]], np.float32)
    t_hit = rc.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()  # [2], inf = no wall
    assert np.isfinite(t_hit).any()
    wall, yaw = float(t_hit.min()), (np.pi / 2, -np.pi / 2)[int(np.argmin(t_hit))]
    state = RobotState(x0, y0, yaw)
    blocked = False
    for _ in range(int((wall + 3.0) / 0.02)):  # 1 m/s at 50 Hz, 3 m past the wall
        state, hit = world.step(state, 1.0, 0.0, 0.02)
        blocked |= bool(hit)
    assert blocked
    assert abs(state.y - y0) < wall - 0.3 + 0.02  # the box front (0.45 m) stops at the wall
    world.close()


def test_tiny_map_refused_at_construction(registry):
    reg, co = registry
    with pytest.raises(SceneError, match="map_too_small"):
        NavEnv(reg, "tiny-street", checkout_root=co)


def test_expert_reaches_goals_and_episode_record(registry):
    env = make(registry, training=False)
    expert = PurePursuitExpert()
    ends = []
    for seed in range(2):
        env.reset(seed=seed)
        start = env.unwrapped.robot_pose()
        expert.reset(env)
        terminated = truncated = False
        while not (terminated or truncated):
            _, r, terminated, truncated, info = env.step(expert.act(env))
        rec = info["nav_episode"]
        ends.append(rec.end)
        assert rec.steps == info["steps"] and rec.path_length > 0
        # where the episode began, aimed and ended, in the scene frame
        assert rec.start_pose == pytest.approx(start)
        assert rec.end_pose == pytest.approx(env.unwrapped.robot_pose())
        assert math.dist(rec.end_pose[:2], rec.goal) <= env.unwrapped.config.reward.success_radius
        assert math.dist(rec.start_pose[:2], rec.goal) > 1.0
    assert ends == ["success", "success"]


def test_comfortable_expert_route_leaves_spl_reference_alone(registry):
    """`episode={"expert_comfort": ...}` (a JSON-friendly nested override) changes the expert's
    route only: the episode, its obstacles and SPL's shortest length stay those of the plain env."""
    plain, comfy = make(registry, training=False), make(registry, training=False, episode={"expert_comfort": 0.9})
    assert comfy.unwrapped.config.episode.expert_comfort == 0.9
    assert comfy.unwrapped.config.episode.clearance == plain.unwrapped.config.episode.clearance
    for seed in range(3):
        plain.reset(seed=seed)
        comfy.reset(seed=seed)
        p, c = plain.unwrapped, comfy.unwrapped
        assert c.shortest == pytest.approx(p.shortest)
        np.testing.assert_allclose(c.actors.shortest_path, p.expert_path())
        np.testing.assert_allclose(c.actors.obstacle_xy(), p.actors.obstacle_xy())
        assert len(c.expert_path()) >= 2 and np.allclose(c.expert_path()[-1], p.expert_path()[-1])
        assert all(c.actors.route_planner.is_free(x, y) for x, y in c.expert_path())


def test_nested_override_builds_a_config_the_env_leaves_unset(registry):
    """`augment={"enabled": False}` (a JSON-friendly override of a field that defaults to None)
    builds the augmentation config from its defaults: a training env then renders the same first
    frame as the evaluation env, and without it the augmentation changes that frame."""
    clean = make(registry, training=True, jitter=False, fidelity="exact", augment={"enabled": False, "fog_prob": 0.0})
    augmented = make(registry, training=True, jitter=False, fidelity="exact")
    evaluation = make(registry, training=False)
    assert not clean.unwrapped.config.augmentation.enabled
    assert clean.unwrapped.config.augment.fog_prob == 0.0
    frames = [env.reset(seed=3)[0]["image"][-1] for env in (clean, augmented, evaluation)]
    np.testing.assert_array_equal(frames[0], frames[2])
    assert np.abs(frames[1].astype(int) - frames[2].astype(int)).mean() > 1.0


def test_expert_steers_off_arcs_that_leave_the_map(registry):
    """Facing the map's edge, the expert's steering keeps its checked arc on the walkable map."""
    env = make(registry, training=False)
    env.reset(seed=0)
    u, conf = env.unwrapped, ExpertConfig(horizon=2.0)
    x, y = u.episode.start
    checked = 0
    for yaw in np.radians(np.arange(0, 360, 30)):
        u.state = RobotState(float(x), float(y), float(yaw))
        if _arc_on_map(u, 0.0, conf.horizon) >= conf.horizon:
            continue  # straight ahead stays on the map: nothing to correct
        s = _safe_steer(u, 0.0, conf)
        if any(_arc_on_map(u, c, conf.horizon) >= conf.horizon for c in np.linspace(-1, 1, 9)):
            assert s != 0.0 and _arc_on_map(u, s, conf.horizon) >= conf.horizon
            checked += 1
    assert checked > 0
    env.close()


def test_expert_tries_other_steering_when_blocked(registry):
    """After a step that left the pose unchanged (as a blocked move does) the expert steers the
    other way; asked twice without a step it answers the same (SB3's env_method may ask twice)."""
    env = make(registry, training=False)
    env.reset(seed=0)
    expert = PurePursuitExpert()
    expert.reset(env)
    first = expert.act(env)
    np.testing.assert_array_equal(expert.act(env), first)  # no step in between: same action
    env.step(np.array([-1.0, first[1]], np.float32))  # speed clamped to 0: the pose stays
    second = expert.act(env)
    assert second[1] != first[1] and abs(second[1]) == 1.0 and np.sign(second[1]) != np.sign(first[1])
    env.step(second)
    assert expert.act(env)[1] == pytest.approx(first[1], abs=0.5)  # moving again: pursuit
    env.close()


def test_topdown_state_keys(registry):
    env = make(registry)
    env.reset(seed=1)
    env.step(np.array([1.0, 0.0], np.float32))
    s = env.unwrapped.topdown_state()
    assert {"grid", "robot_xy", "robot_yaw", "path", "planned_path", "goal", "obstacles",
            "pedestrians"} <= set(s)
    assert s["path"].shape == (2, 2) and s["obstacles"].shape[1] == 2
