"""Env benchmark: scripted-expert SR / SPL / Cost and env steps per second split by part.

Scenes: the synthetic street's ground-truth bundle at ~75k and 200k splats (built into a tmp
registry, any valid bundle works), plus `--registry ROOT --scene ID` (e.g. the factory demo
scene made by `vid2sim demo`). Expert: evaluation mode (no jitter, no augmentation), 0-5
obstacles per episode. Speed: one numba thread (one core), the expert driving (training mode:
jitter + augmentation on), resets excluded; steps per CPU-second of the process (= per core;
wall-clock is polluted by other load) for the exact render and the fast render (sim-ready set,
`EnvConfig.fidelity="fast"`, at each `--fast` keep_mass[:fit_iterations]), CPU ms per step
split into render (splats or mesh), physics, obstacles, pedestrians, augment, reward, other
(frame stacking, info, goal vector, wrappers; the expert's own time is left out); PSNR of the
fast splat RGB render against the exact one at every 10th step's camera pose, mean and worst
over the poses (identical images count as 99 dB; depth runs too).

Factory scenes by name (`--scenes demo gopro`): the bundles `benchmarks/env_scenes.py` builds
and caches (the `make demo` street; the shared GoPro clip from ../shared/data); one that is not
built is skipped with the command that builds it.

Usage: .venv/bin/python benchmarks/envs.py [--episodes 20] [--steps 200]
       [--scenes demo gopro] [--registry ROOT --scene ID] [--factory ROOT ID ...] [--skip-gt]
       [--no-speed] [--no-expert] [--fast default 0.85:600 0.95] [--no-exact] [--quick]
--fast: `default` is the env's default fast path (FastRenderConfig()); KEEP[:FIT] changes
keep_mass (and fit iterations) from it; a `+views[=MASS]` suffix turns view sets on
(`FastRenderConfig.view_keep_mass`, default 0.98; `=MASS:RADIUS:HEADING:PER_M2` sets
view_radius, view_heading_deg and views_per_m2 too), e.g. `default+views 0.95+views=0.99:1.5:40:10`.
--quick: one 75k GT bundle, 3 expert episodes, 60 speed steps, the default fast path (smoke run).
"""

from __future__ import annotations

import argparse
from collections import Counter
from dataclasses import replace
import tempfile
import time
from pathlib import Path

import gymnasium
import numba
import numpy as np

from common import Run, add_run_args
from env_scenes import CACHE as SCENE_CACHE, find_bundle, scene_id
import vid2sim.envs  # noqa: F401  (registers the env ids)
from vid2sim.envs.config import FastRenderConfig, RewardConfig
from vid2sim.envs.expert import PurePursuitExpert
from vid2sim.envs.metrics import summarize
from vid2sim.envs.nav_env import PARTS
from vid2sim.envs.rendering import SplatView
from vid2sim.factory.synthetic import GTBundleConfig, generate_street, preset, render_video, write_ground_truth_bundle
from vid2sim.registry import Registry

CHECKOUTS = Path(tempfile.mkdtemp(prefix="vid2sim-bench-checkouts-"))
SPEED_RUNS = (("PointNav", "rgb"), ("PointNav", "depth"), ("SocialNav", "rgb"))


def gt_registry(root: Path, splat_counts: tuple[int, ...]) -> list[tuple[str, str]]:
    """GT bundles of one synthetic street (10 s walk) at several splat counts -> (root, scene id)."""
    conf = preset("test", seed=11, duration_s=10.0)
    scene = generate_street(conf)
    clip = render_video(scene, conf, root / "clip")
    reg = Registry(root / "registry")
    out = []
    for n in splat_counts:
        sid = f"gt-street-{n // 1000}k"
        bundle = write_ground_truth_bundle(scene, clip, root / sid, GTBundleConfig(n_splats=n, scene_id=sid))
        reg.add(bundle)
        out.append((reg.root, sid))
    return out


def make(root: str, scene: str, task: str = "PointNav", variant: str = "rgb", **kw) -> gymnasium.Env:
    return gymnasium.make(f"vid2sim/{task}-v0", registry=root, scenes=scene, variant=variant,
                          checkout_root=CHECKOUTS, **kw)


def expert_table(run: Run, label: str, root: str, scene: str, episodes: int, max_steps: int) -> tuple:
    """Summary of the scripted expert's episodes and the count of each episode end."""
    env = make(root, scene, training=False, reward=RewardConfig(max_steps=max_steps))
    expert, records, ends = PurePursuitExpert(), [], Counter()
    for seed in range(episodes):
        env.reset(seed=seed)
        expert.reset(env)
        done = False
        while not done:
            _, _, term, trunc, info = env.step(expert.act(env))
            done = term or trunc
        records.append(info["nav_episode"])
        e = info["nav_episode"]
        ends[e.end] += 1
        ends["obstacles"] += len(env.unwrapped.actors.obstacle_xy())
        x, y, _ = env.unwrapped.robot_pose()
        run.record_all(f"{label}: expert seed {seed}",
                       {"end": e.end, "steps": e.steps, "path_m": e.path_length, "shortest_m": e.shortest_length,
                        "collisions": e.collision_events, "obstacles": len(env.unwrapped.actors.obstacle_xy()),
                        "end_x": x, "end_y": y}, {"path_m": "m", "shortest_m": "m", "end_x": "m", "end_y": "m"},
                       {"max_steps": max_steps, "mode": "evaluation"})
        print(f"  seed {seed}: {e.end}, {e.steps} steps, {e.path_length:.1f} / {e.shortest_length:.1f} m, "
              f"{e.collision_events} collisions, {len(env.unwrapped.actors.obstacle_xy())} obstacles, "
              f"ended at ({x:.2f}, {y:.2f})", flush=True)
    env.close()
    return summarize(records), ends


PSNR_SAME = 99.0  # dB counted for identical images (so that a mean over poses stays finite)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR (dB) of uint8 images a vs b [H, W, 3]; PSNR_SAME when they are identical."""
    mse = float(((a.astype(np.float64) - b.astype(np.float64)) ** 2).mean())
    return PSNR_SAME if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


def speed(root: str, scene: str, task: str, variant: str, steps: int, fidelity: str,
          fast: FastRenderConfig = FastRenderConfig(), every: int = 10
          ) -> tuple[float, float, dict, list, int]:
    """(steps per CPU-s, steps per wall-s, CPU ms per step by part, PSNR of fast vs exact
    every `every` steps (fast only), splats rendered) of the expert driving, resets excluded."""
    env = make(root, scene, task, variant, fidelity=fidelity, fast=fast)
    u, expert = env.unwrapped, PurePursuitExpert()
    env.reset(seed=100)
    view = u.world.view
    n_splats = view.sim.model.num if fidelity == "fast" else u.world.assets.splats.num
    expert.reset(env)
    env.step(expert.act(env))  # warm-up (JIT)
    u.timings.clear()
    cpu, wall, done_steps, seed, poses = 0.0, 0.0, 0, 101, []
    while done_steps < steps:
        action = expert.act(env)  # the agent's time is not the env's
        c0, w0 = time.process_time(), time.perf_counter()
        _, _, term, trunc, _ = env.step(action)
        cpu += time.process_time() - c0
        wall += time.perf_counter() - w0
        done_steps += 1
        if done_steps % every == 0:
            poses.append(u.last_world_to_cam.copy())
        if term or trunc:  # reset time stays out of the per-part figures too
            before = dict(u.timings)
            env.reset(seed=seed)
            expert.reset(env)
            u.timings.clear()
            u.timings.update(before)
            seed += 1
    parts = {k: 1e3 * u.timings.get(k, 0.0) / done_steps for k in PARTS}
    parts["other"] = 1e3 * cpu / done_steps - sum(parts.values())
    quality = []
    if fidelity == "fast":
        exact = SplatView(u.world.assets.splats, u.config.camera)
        quality = [psnr(view.draw(w)[0], exact.draw(w)[0]) for w in poses]
    env.close()
    return done_steps / cpu, done_steps / wall, parts, quality, n_splats


def fast_config(spec: str) -> tuple[FastRenderConfig, str]:
    """The fast path setting a --fast entry names (`default` or KEEP[:FIT], then optionally
    `+views[=MASS[:RADIUS[:HEADING[:PER_M2]]]]`), and its label."""
    spec, plus, views = spec.partition("+views")
    if spec == "default":
        conf, label = FastRenderConfig(), "fast (default)"
    else:
        keep, _, fit = spec.partition(":")
        label = f"fast k={keep}" + (f" fit {fit}" if fit else "")
        conf = replace(FastRenderConfig(), keep_mass=float(keep), fit_iterations=int(fit or 0))
    if not plus:
        return conf, label
    fields = [float(v) for v in views.removeprefix("=").split(":")] if views else [0.98]
    names = ("view_keep_mass", "view_radius", "view_heading_deg", "views_per_m2")
    conf = replace(conf, **dict(zip(names, fields)))
    return conf, f"{label} + view sets " + ":".join(f"{v:g}" for v in fields)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--registry", default=None)
    ap.add_argument("--scene", default=None)
    ap.add_argument("--factory", nargs=2, action="append", default=[], metavar=("ROOT", "ID"),
                    help="another registry scene (repeatable), e.g. the GoPro factory scene")
    ap.add_argument("--skip-gt", action="store_true")
    ap.add_argument("--no-speed", action="store_true", help="only the expert table")
    ap.add_argument("--no-expert", action="store_true", help="only the speed table")
    ap.add_argument("--gt-splats", type=int, nargs="*", default=[],
                    help="splat counts of the synthetic GT bundles (default 75k, and 200k for speed)")
    ap.add_argument("--no-exact", action="store_true", help="speed: only the fast render path")
    ap.add_argument("--scenes", nargs="*", default=[], metavar="NAME",
                    help="factory scenes built by benchmarks/env_scenes.py (demo, gopro)")
    ap.add_argument("--fast", nargs="+", default=["default"], metavar="default|KEEP[:FIT][+views[=MASS:...]]",
                    help="fast path settings to measure: 'default' (the env's default), or a "
                         "sim-ready keep_mass, optionally with fit iterations (e.g. 0.9:600)")
    ap.add_argument("--max-steps", type=int, default=600,
                    help="expert episodes: step limit (the env default is the paper's 3000)")
    ap.add_argument("--quick", action="store_true",
                    help="one 75k GT bundle, 3 episodes, 60 speed steps, fast 0.9 without fit")
    add_run_args(ap)
    args = ap.parse_args()
    if args.quick:
        args.episodes, args.steps = min(args.episodes, 3), min(args.steps, 60)
        args.gt_splats, args.fast = args.gt_splats or [75_000], ["default"]
    numba.set_num_threads(1)
    with Run("envs", args, config={"numba_threads": 1}) as run:
        bench(run, args)


def bench(run: Run, args: argparse.Namespace) -> None:
    print("numba threads: 1")
    scenes: list[tuple[str, str, str]] = []
    pairs = ([(args.registry, args.scene)] if args.registry and args.scene else []) + args.factory
    for name in args.scenes:
        bundle = find_bundle(name)
        if bundle is None:
            run.skip(name, f"not built: .venv/bin/python benchmarks/env_scenes.py {name}")
            continue
        pairs.append((str(SCENE_CACHE / name / "registry"), scene_id(bundle)))
    for root, sid in pairs:
        n = Registry(root).show(sid).num_splats
        scenes.append((root, sid, f"{sid} (factory, {n // 1000}k splats)"))
    if not args.skip_gt:
        tmp = Path(tempfile.mkdtemp(prefix="vid2sim-bench-envs-"))
        counts = tuple(args.gt_splats) or ((75_000,) if args.no_speed else (75_000, 200_000))
        for root, sid in gt_registry(tmp, counts):
            scenes.append((root, sid, f"{sid} (synthetic GT bundle)"))
    print(f"\nscripted expert, PointNav, 0-5 obstacles, evaluation mode, {args.episodes} episodes, "
          f"limit {args.max_steps} steps")
    print("| scene | SR | SPL | Cost | SNS | obstacles / episode | episode ends |\n|---|---|---|---|---|---|---|")
    for root, sid, label in ([] if args.no_expert else scenes):
        if "200k" in sid:
            continue  # same street as the 75k bundle: the expert does not look at the splats
        s, ends = expert_table(run, label, root, sid, args.episodes, args.max_steps)
        n_obs = ends.pop("obstacles", 0) / max(s.episodes, 1)
        why = ", ".join(f"{k} {n}" for k, n in ends.most_common())
        run.record_all(f"{label}: scripted expert, PointNav, {args.episodes} episodes",
                       {"SR": s.sr, "SPL": s.spl, "Cost": s.cost, "SNS": s.sns, "obstacles per episode": n_obs,
                        "episode ends": why}, config={"max_steps": args.max_steps, "obstacles": "0-5"})
        print(f"| {label} | {100 * s.sr:.0f} % | {s.spl:.3f} | {s.cost:.2f} | {s.sns:.3f} | {n_obs:.1f} | {why} |",
              flush=True)
    if args.no_speed:
        return
    print(f"\nenv steps per CPU-second, one core ({args.steps} steps, expert actions, training mode), "
          "CPU ms per step by part; fast = sim-ready set (keep_mass k, colours baked, fit iterations, t_stop "
          f"{FastRenderConfig().t_stop}), PSNR of its splat render vs exact at every 10th step's pose")
    print("| scene | task / obs | render | splats | steps/CPU-s | steps/wall-s | PSNR mean (min) dB | "
          + " | ".join(PARTS) + " | other |")
    print("|---|---|---|---|---|---|---|" + "---|" * (len(PARTS) + 1))
    paths = ([] if args.no_exact else [("exact", "")]) + [("fast", f) for f in args.fast]
    for root, sid, label in scenes:
        for task, variant in SPEED_RUNS:
            for fidelity, spec in paths:
                conf, name = fast_config(spec) if fidelity == "fast" else (FastRenderConfig(), "exact")
                sps, wps, parts, q, n = speed(root, sid, task, variant, args.steps, fidelity, conf)
                qual = f"{np.mean(q):.1f} ({min(q):.1f})" if q else "-"
                run.record_all(f"{label}: {task} {variant}, {name}",
                               {"splats": n, "steps_per_cpu_s": sps, "steps_per_wall_s": wps,
                                "psnr_vs_exact_mean": float(np.mean(q)) if q else None,
                                "psnr_vs_exact_min": min(q) if q else None,
                                **{f"{k} CPU ms/step": parts[k] for k in (*PARTS, "other")}},
                               {"steps_per_cpu_s": "steps/CPU-s", "steps_per_wall_s": "steps/s",
                                "psnr_vs_exact_mean": "dB", "psnr_vs_exact_min": "dB",
                                **{f"{k} CPU ms/step": "ms" for k in (*PARTS, "other")}},
                               {"steps": args.steps, "mode": "training", "t_stop": conf.t_stop})
                cells = " | ".join(f"{parts[k]:.2f}" for k in (*PARTS, "other"))
                print(f"| {label} | {task} {variant} | {name} | {n // 1000}k | {sps:.0f} | {wps:.0f} | "
                      f"{qual} | {cells} |", flush=True)


if __name__ == "__main__":
    main()
