"""Learnability at CPU budgets: privileged agent, pixel agent, baselines, a tiny study.

    python benchmarks/learning.py sanity --trials 20    # scripted policies' returns under the reward
    python benchmarks/learning.py privileged --steps 40000 [--warmup random --bc-weight 0] [--root ...]
        (defaults: 31 rays over 200 deg, 2.5 m range, speed mapped over the whole action range)
    python benchmarks/learning.py pixel --steps 3000
    python benchmarks/learning.py baselines --trials 25
    python benchmarks/learning.py failures --runs RUN    # first contact / stop of each held-out trial
    (study: vid2sim study --registry ROOT/registry --counts 1,3 --seeds 2 --env privileged ...)

Scenes: synthetic-street ground-truth bundles (benchmarks/street_registry.py, seeds 1-6); the
registry's split (seed 0) holds out whole streets. Held-out episodes: `vid2sim eval policy`'s
protocol (test scenes x trials, seeds 1000 + k, 0-5 static obstacles where the envs place them,
no jitter). Every figure prints its budget (env steps); the harness records the hardware and commit.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import torch  # noqa: E402
from common import Run, add_run_args  # noqa: E402
from street_registry import build  # noqa: E402

from vid2sim.envs.expert import PurePursuitExpert  # noqa: E402
from vid2sim.registry import Registry  # noqa: E402
from vid2sim.training.config import SACConfig, TrainConfig  # noqa: E402
from vid2sim.training.evaluate import (EvalConfig, eval_env_config, evaluate, held_out_scenes,  # noqa: E402
                                       load_policy, run_observation_kwargs)
from vid2sim.training.privileged import PRIVILEGED_ID  # noqa: E402
from vid2sim.training.sac import train  # noqa: E402
from vid2sim.training.wrappers import StuckTermination  # noqa: E402

PRIV_SAC = SACConfig(learning_starts=5000, batch_size=256, buffer_size=200_000, gradient_steps=5, train_freq=1,
                     use_sde=False, warmup="expert", ent_coef="auto_0.01", net_arch=(128, 128),
                     bc_weight=1.0)  # with --rays 31 --max-range 2.5 --action-map full (the defaults):
# docs/studies/privileged_agent.md


RUN = None  # the harness run (benchmarks/common.py) of this invocation


def report(name: str, rep, budget: str) -> dict:
    m = rep.metrics
    row = {"agent": name, "budget": budget, "episodes": rep.episodes,
           **{k: [round(m[k].mean, 3), round(m[k].low, 3), round(m[k].high, 3)] for k in ("sr", "spl", "cost")}}
    print(json.dumps(row), flush=True)
    for k in ("sr", "spl", "cost"):
        RUN.record(name, k, m[k].mean, "", {"ci95": [m[k].low, m[k].high], "episodes": rep.episodes,
                                            "budget": budget})
    return row


def rays(args) -> dict:
    """Privileged env arguments of `--rays` / `--max-range` (default: the env's 11 rays over 200 deg, 5 m)."""
    return {**({"n_rays": args.rays} if args.rays else {}), **({"max_range": args.max_range} if args.max_range else {})}


def run_privileged(args) -> None:
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    run = args.root / f"privileged_{args.steps}_h{args.train_max_steps}_s{args.seed}{args.tag}"
    config = TrainConfig(run_dir=str(run), total_steps=args.steps, env_id=PRIVILEGED_ID,
                         env_module="vid2sim.training.privileged",
                         env_kwargs={"training": True, "max_steps": args.train_max_steps, **rays(args)},
                         registry=reg, n_envs=args.n_envs, n_actors=0, seed=args.seed, checkpoint_every=5000,
                         action_map=args.action_map,
                         stuck_steps=args.stuck_steps or None,
                         sac=replace(PRIV_SAC, use_sde=args.sde, warmup=args.warmup,
                                                 learning_starts=args.learning_starts, ent_coef=args.ent_coef,
                                                 gradient_steps=args.gradient_steps, bc_weight=args.bc_weight,
                                                 bc_pretrain_steps=args.bc_pretrain,
                                                 net_arch=tuple(int(n) for n in args.net.split(","))))
    cpu0 = time.process_time()
    result = train(config, progress_bar=False, log_every=2000)
    cpu = time.process_time() - cpu0
    for row in result.history:
        print(json.dumps({k: round(v, 3) for k, v in row.items()}), flush=True)
    rep = evaluate(EvalConfig(registry=reg, policy=str(run), trials=args.trials, env_id=PRIVILEGED_ID,
                              checkout_root=str(args.root / "checkouts"), env_kwargs=rays(args)))
    (run / "eval.json").write_text(rep.to_json())
    report("privileged SAC", rep, f"{result.num_timesteps} env steps, {result.wall_s:.0f} s wall, {cpu:.0f} s CPU")


# ------------------------------------------------------------------ sanity: the reward ranks policies right
def scripted(name: str, env, rng):
    """Action function of a scripted policy on the privileged observation [dist/30, heading/pi, ranges]."""
    expert = PurePursuitExpert()
    steer_gain = math.pi / env.unwrapped.config.robot.max_steer  # heading (rad) -> normalised steering
    policies = {"expert": lambda obs: expert.act(env), "random": lambda obs: rng.uniform(-1, 1, 2),
                "straight-at-goal": lambda obs: np.array([1.0, np.clip(obs[1] * steer_gain, -1, 1)]),
                "stand-still": lambda obs: np.array([-1.0, 0.0])}
    return expert, policies[name]


def run_sanity(args) -> None:
    """Mean return, length and ends of scripted policies on training episodes, without and with the
    training-only `StuckTermination` (600-step training horizon)."""
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    scenes = list(Registry(reg).split(seed=0).train)
    for stuck in (0, args.stuck_steps):
        env = gym.make(PRIVILEGED_ID, registry=reg, scenes=scenes, training=True, max_steps=args.train_max_steps,
                       checkout_root=str(args.root / "checkouts"))
        env = StuckTermination(env, stuck) if stuck else env
        for name in ("expert", "straight-at-goal", "random", "stand-still"):
            expert, act = scripted(name, env, np.random.default_rng(0))
            returns, lengths, ends = [], [], Counter()
            for k in range(args.trials):
                obs, _ = env.reset(seed=k)
                expert.reset(env)
                done, ret, n = False, 0.0, 0
                while not done:
                    obs, r, terminated, truncated, info = env.step(np.asarray(act(obs), np.float32))
                    ret, n, done = ret + r, n + 1, terminated or truncated
                returns.append(ret), lengths.append(n)
                ends[info["end"]] += 1
            print(json.dumps({"stuck_termination": stuck, "policy": name, "episodes": args.trials,
                              "mean_return": round(float(np.mean(returns)), 1),
                              "mean_length": round(float(np.mean(lengths)), 1), "ends": dict(ends)}), flush=True)
        env.close()


def run_baselines(args) -> None:
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    for policy in ("random", "expert"):
        rep = evaluate(EvalConfig(registry=reg, policy=policy, trials=args.trials, max_steps=args.eval_max_steps,
                                  checkout_root=str(args.root / "checkouts"),
                                  env_id=PRIVILEGED_ID if args.privileged else None))
        report(f"{policy}{' (privileged env)' if args.privileged else ''}", rep, "no training")


def run_pixel(args) -> None:
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    run = args.root / f"pixel_{args.steps}"
    sac = SACConfig(learning_starts=min(1000, args.steps // 3), batch_size=64, buffer_size=20_000, train_freq=4,
                    ent_coef=args.ent_coef)
    config = TrainConfig(run_dir=str(run), total_steps=args.steps, env_kwargs={"training": True}, registry=reg,
                         n_envs=2, n_actors=0, seed=args.seed, checkpoint_every=1000, sac=sac,
                         stuck_steps=args.stuck_steps or None)
    t0, cpu0 = time.perf_counter(), time.process_time()
    result = train(config, progress_bar=False, log_every=500)
    cpu = time.process_time() - cpu0
    for row in result.history:
        print(json.dumps({k: round(v, 3) for k, v in row.items()}), flush=True)
    rep = evaluate(EvalConfig(registry=reg, policy=str(run), trials=args.trials, max_steps=args.eval_max_steps,
                              checkout_root=str(args.root / "checkouts")))
    (run / "eval.json").write_text(rep.to_json())
    report("pixel SAC", rep, f"{result.num_timesteps} env steps, {time.perf_counter() - t0:.0f} s wall, "
                                 f"{cpu:.0f} s CPU")


def run_heldout(args) -> None:
    """Held-out SR / SPL / Cost of every `checkpoints/step_N.zip` of `--runs` (privileged env, eval protocol)."""
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    for run in args.runs:
        ckpts = sorted((run / "checkpoints").glob("step_*.zip"), key=lambda p: int(p.stem.split("_")[1]))
        for ckpt in ckpts[::args.every]:
            rep = evaluate(EvalConfig(registry=reg, policy=str(ckpt), trials=args.trials, env_id=PRIVILEGED_ID,
                                      checkout_root=str(args.root / "checkouts")))
            report(f"{run.name}/{ckpt.stem}", rep, f"{ckpt.stem.split('_')[1]} env steps")


def first_event(env, act, nrays: int, cap: int) -> dict:
    """Roll one episode until it ends, first touches something, or stands still for 50 steps."""
    u, still, stops, obs = env.unwrapped, 0, 0, env.unwrapped._obs()
    obstacles = set(u.actors.obstacles.body_ids) if u.actors.obstacles is not None else set()
    for t in range(cap):
        a = act(env, obs)
        stops += int(a[0] <= 0.0)
        x0, y0, _ = u.robot_pose()
        obs, _, terminated, truncated, info = env.step(a)
        x1, y1, _ = u.robot_pose()
        still = still + 1 if math.hypot(x1 - x0, y1 - y0) < 0.02 else 0
        event = info["end"] if terminated or truncated else None
        if info["collided"]:
            event = "contact-" + ("obstacle" if set(u.world.physics.contacts()[0]) & obstacles else "street")
        elif still >= 50:
            event = "stopped"
        if event:
            break
    mesh = obs[2:2 + nrays] * u.max_range
    return {"event": event or f"running@{cap}", "steps": t + 1, "goal_m": round(u.distance(), 1),
            "stop_cmds": round(stops / (t + 1), 2), "speed": round(float(a[0]), 2), "steer": round(float(a[1]), 2),
            "nearest_m": round(float(mesh.min()), 2), "nearest_deg": round(float(np.degrees(u.angles[mesh.argmin()])))}


def run_failures(args) -> None:
    """Where a run's deterministic policy fails on the held-out episodes: per trial the first contact
    (street mesh or obstacle), a stop (50 steps without motion) or the end, with its last action."""
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    for run in args.runs:
        config = EvalConfig(registry=reg, policy=str(run), trials=args.trials, env_id=PRIVILEGED_ID,
                            checkout_root=str(args.root / "checkouts"))
        env_id, env_conf = eval_env_config(config)
        scenes = held_out_scenes(config)
        env = gym.make(env_id, registry=reg, scenes=scenes, config=env_conf, checkout_root=config.checkout_root,
                       **run_observation_kwargs(str(run)))
        act, _ = load_policy(str(run), 0)
        events = Counter()
        for sid in scenes:
            for k in range(args.trials):
                env.reset(seed=config.seed + k, options={"scene_id": sid})
                row = first_event(env, act, env.unwrapped.n_rays, cap=400)
                events[row["event"]] += 1
                print(json.dumps({"run": run.name, "scene": sid, "trial": k, **row}), flush=True)
        env.close()
        print(json.dumps({"run": run.name, "events": dict(events)}), flush=True)


# ------------------------------------------------------------------ curves
def tb_curve(run: Path) -> dict[str, list[tuple[int, float]]]:
    """(env step, value) series of training success and return from a run's TensorBoard logs."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    out: dict[str, list[tuple[int, float]]] = {"nav/success": [], "rollout/ep_return_mean": []}
    for folder in sorted((run / "tb").iterdir()):
        acc = EventAccumulator(str(folder))
        acc.Reload()
        for tag in out:
            if tag in acc.Tags()["scalars"]:
                out[tag] += [(e.step, e.value) for e in acc.Scalars(tag)]
    return out


def run_curve(args) -> None:
    """PNG of training success and return (last-100-episode means) against env steps for `--runs`."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for run in args.runs:
        curve = tb_curve(run)
        for ax, tag in zip(axes, curve):
            steps, values = zip(*curve[tag]) if curve[tag] else ((), ())
            ax.plot(steps, values, label=run.name)
    for ax, title in zip(axes, ("training success (last 100 episodes)", "training return (last 100 episodes)")):
        ax.set_xlabel("env steps")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("what", choices=["sanity", "privileged", "pixel", "baselines", "curve", "heldout",
                                       "failures"])
    ap.add_argument("--root", type=Path, default=Path("/tmp/training-streets"))
    ap.add_argument("--steps", type=int, default=30_000)
    ap.add_argument("--trials", type=int, default=25)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--eval-max-steps", type=int, default=None, help="episode limit in evaluation (default 3000)")
    ap.add_argument("--train-max-steps", type=int, default=600, help="privileged: training episode limit")
    ap.add_argument("--stuck-steps", type=int, default=10, help="training: end blocked episodes (0 = off)")
    ap.add_argument("--n-envs", type=int, default=5)
    ap.add_argument("--sde", action="store_true", help="privileged: gSDE exploration (paper) instead of Gaussian")
    ap.add_argument("--warmup", default="expert", choices=["expert", "random"], help="privileged: warm-up actions")
    ap.add_argument("--learning-starts", type=int, default=5000)
    ap.add_argument("--gradient-steps", type=int, default=5, help="privileged: per vector step (5 envs: UTD 1)")
    ap.add_argument("--bc-weight", type=float, default=1.0, help="privileged: BC actor steps on the demonstrations")
    ap.add_argument("--bc-pretrain", type=int, default=0,
                    help="privileged: BC + TD gradient steps on the demonstrations before SAC acts")
    ap.add_argument("--net", default="128,128", help="privileged: actor/critic hidden sizes")
    ap.add_argument("--ent-coef", default="auto_0.01", help="privileged: SB3 ent_coef (paper preset: auto = 1.0 start)")
    ap.add_argument("--rays", type=int, default=31, help="privileged: ray count over 200 deg (0: the env's 11)")
    ap.add_argument("--max-range", type=float, default=2.5, help="privileged: ray range in m (0: the env's 5)")
    ap.add_argument("--action-map", default="full", choices=["clamp", "full"],
                    help="privileged: policy speed -> env speed (training/actions.py; full: (p + 1) / 2)")
    ap.add_argument("--tag", default="")
    ap.add_argument("--runs", type=Path, nargs="*", default=[], help="curve: run folders")
    ap.add_argument("--every", type=int, default=1, help="heldout: every k-th checkpoint")
    ap.add_argument("--out", type=Path, default=Path("learning_curve.png"), help="curve: PNG path")
    ap.add_argument("--privileged", action="store_true", help="baselines: on the privileged env (same episodes)")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (1: steadier on a shared machine)")
    add_run_args(ap)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    global RUN
    commands = {"failures": run_failures, "heldout": run_heldout, "curve": run_curve, "sanity": run_sanity,
                "privileged": run_privileged, "pixel": run_pixel, "baselines": run_baselines}
    with Run("learning", args) as RUN:
        commands[args.what](args)


if __name__ == "__main__":
    main()
