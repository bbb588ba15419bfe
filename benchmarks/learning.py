"""Learnability at CPU budgets (issue 13): privileged agent, pixel agent, baselines, a tiny study.

    python benchmarks/learning.py privileged --steps 30000 [--root /tmp/training-streets]
    python benchmarks/learning.py pixel --steps 3000
    python benchmarks/learning.py baselines --trials 25
    (study: vid2sim study --registry ROOT/registry --counts 1,3 --seeds 2 --env privileged ...)

Scenes: synthetic-street ground-truth bundles (benchmarks/street_registry.py, seeds 1-6); the
registry's split (seed 0) holds out whole streets. Held-out episodes: `vid2sim eval policy`'s
protocol (test scenes x trials, seeds 1000 + k, 0-5 static obstacles where the envs place them,
no jitter). Every figure prints its budget (env steps) and the machine load.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import torch  # noqa: E402
from street_registry import build  # noqa: E402

from vid2sim.training.config import SACConfig, TrainConfig  # noqa: E402
from vid2sim.training.evaluate import EvalConfig, evaluate  # noqa: E402
from vid2sim.training.privileged import PRIVILEGED_ID  # noqa: E402
from vid2sim.training.sac import train  # noqa: E402

PRIV_SAC = SACConfig(learning_starts=5000, batch_size=256, buffer_size=200_000, gradient_steps=2, train_freq=1,
                     use_sde=False, warmup="expert", ent_coef="auto_0.01")


def header() -> None:
    print(f"# {platform.machine()}, {os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}; command: {' '.join(sys.argv)}",
          flush=True)


def report(name: str, rep, budget: str) -> dict:
    m = rep.metrics
    row = {"agent": name, "budget": budget, "episodes": rep.episodes,
           **{k: [round(m[k].mean, 3), round(m[k].low, 3), round(m[k].high, 3)] for k in ("sr", "spl", "cost")}}
    print(json.dumps(row), flush=True)
    return row


def run_privileged(args) -> None:
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    run = args.root / f"privileged_{args.steps}_h{args.train_max_steps}_s{args.seed}{args.tag}"
    config = TrainConfig(run_dir=str(run), total_steps=args.steps, env_id=PRIVILEGED_ID,
                         env_module="vid2sim.training.privileged",
                         env_kwargs={"training": True, "max_steps": args.train_max_steps},
                         registry=reg, n_envs=args.n_envs, n_actors=0, seed=args.seed, checkpoint_every=5000,
                         stuck_steps=args.stuck_steps or None, sac=replace(PRIV_SAC, use_sde=args.sde, warmup=args.warmup,
                                                 learning_starts=args.learning_starts, ent_coef=args.ent_coef))
    result = train(config, progress_bar=False, log_every=2000)
    for row in result.history:
        print(json.dumps({k: round(v, 3) for k, v in row.items()}), flush=True)
    rep = evaluate(EvalConfig(registry=reg, policy=str(run), trials=args.trials, env_id=PRIVILEGED_ID,
                              checkout_root=str(args.root / "checkouts")))
    (run / "eval.json").write_text(rep.to_json())
    report("privileged SAC", rep, f"{result.num_timesteps} env steps, {result.wall_s:.0f} s wall")


def run_baselines(args) -> None:
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    for policy in ("random", "expert"):
        rep = evaluate(EvalConfig(registry=reg, policy=policy, trials=args.trials, max_steps=args.eval_max_steps,
                                  checkout_root=str(args.root / "checkouts")))
        report(policy, rep, "no training")


def run_pixel(args) -> None:
    reg = str(build(args.root, [1, 2, 3, 4, 5, 6]).root)
    run = args.root / f"pixel_{args.steps}"
    sac = SACConfig(learning_starts=min(1000, args.steps // 3), batch_size=64, buffer_size=20_000, train_freq=4)
    config = TrainConfig(run_dir=str(run), total_steps=args.steps, env_kwargs={"training": True}, registry=reg,
                         n_envs=2, n_actors=0, seed=args.seed, checkpoint_every=1000, sac=sac)
    t0 = time.perf_counter()
    result = train(config, progress_bar=False, log_every=500)
    for row in result.history:
        print(json.dumps({k: round(v, 3) for k, v in row.items()}), flush=True)
    rep = evaluate(EvalConfig(registry=reg, policy=str(run), trials=args.trials, max_steps=args.eval_max_steps,
                              checkout_root=str(args.root / "checkouts")))
    (run / "eval.json").write_text(rep.to_json())
    report("pixel SAC", rep, f"{result.num_timesteps} env steps, {time.perf_counter() - t0:.0f} s wall")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("what", choices=["privileged", "pixel", "baselines"])
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
    ap.add_argument("--ent-coef", default="auto_0.01", help="privileged: SB3 ent_coef (paper preset: auto = 1.0 start)")
    ap.add_argument("--tag", default="")
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (1: steadier on a shared machine)")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    header()
    {"privileged": run_privileged, "pixel": run_pixel, "baselines": run_baselines}[args.what](args)
    print(f"# load after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
