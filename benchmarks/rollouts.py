"""Env steps per second: RayVecEnv with 1 and 2 actors vs SB3's DummyVecEnv and SubprocVecEnv.

    python benchmarks/rollouts.py [--registry ROOT] [--envs 4] [--steps 100]

Same env specs (vid2sim/PointNav-v0, RGB, synthetic-street ground-truth scenes dealt round-robin)
for every backend, in one run; random actions; the first reset and 5 warm-up steps are not timed.
Builds a 2-street registry under /tmp when --registry is not given.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import ray
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import Run, add_run_args  # noqa: E402
from street_registry import build  # noqa: E402

from vid2sim.training.rollouts import RayVecEnv, init_ray, RayVecEnvConfig, specs_for_scenes  # noqa: E402


def time_env(env, steps: int) -> float:
    env.seed(0)
    env.reset()
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (steps + 5, env.num_envs, 2)).astype(np.float32)
    for a in acts[:5]:
        env.step(a)
    t0 = time.perf_counter()
    for a in acts[5:]:
        env.step(a)
    return steps * env.num_envs / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--registry", type=Path)
    ap.add_argument("--envs", type=int, default=4)
    ap.add_argument("--steps", type=int, default=100, help="vector steps timed per backend")
    add_run_args(ap)
    args = ap.parse_args()
    with Run("rollouts", args) as run:
        bench(run, args)


def bench(run: Run, args: argparse.Namespace) -> None:
    root = args.registry or build(Path("/tmp/vid2sim-bench-streets"), [1, 2]).root
    scenes = ["synthetic-street-s1", "synthetic-street-s2"]
    specs = specs_for_scenes("vid2sim/PointNav-v0", scenes, args.envs, {"registry": str(root), "training": False})
    init_ray(num_cpus=2)
    results = {}
    backends = {"DummyVecEnv": lambda: DummyVecEnv([s.make for s in specs]),
                # spawn: deltalake's tokio runtime is not fork-safe
                "SubprocVecEnv": lambda: SubprocVecEnv([s.make for s in specs], start_method="spawn"),
                "RayVecEnv 1 actor": lambda: RayVecEnv(specs, RayVecEnvConfig(n_actors=1)),
                "RayVecEnv 2 actors": lambda: RayVecEnv(specs, RayVecEnvConfig(n_actors=2))}
    for name, make in backends.items():
        env = make()
        results[name] = time_env(env, args.steps)
        env.close()
        run.record(name, "env_steps_per_s", results[name], "steps/s",
                   {"envs": args.envs, "vector_steps": args.steps, "env": "vid2sim/PointNav-v0 rgb"})
        print(f"{name:20s} {results[name]:8.1f} env steps/s  ({args.envs} envs, {args.steps} vector steps)",
              flush=True)
    ray.shutdown()


if __name__ == "__main__":
    main()
