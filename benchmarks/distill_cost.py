"""What a DAgger round of the pixel student costs in CPU-seconds: the learner's fit and the collection, by threads.

    python benchmarks/distill_cost.py --root /tmp/vid2sim-distill --streets 40 [--threads 1 2]
    python benchmarks/distill_cost.py --quick     # 6 streets, few steps and updates (smoke run)

Fit: `training/distill.fit` of the default student (`StudentConfig()`: 2 frames pooled to 36 x 64)
for --updates batches of `DistillConfig.batch_size` drawn from random frames (the cost does not
depend on the pixels), per thread count, with the channels-last conv weights the student is built
with and with plain contiguous ones. Collection: the `Collector` stepping --envs in-process training envs
of the registry's training streets (exact render fidelity, the teacher labelling every state),
the teacher driving (its episodes are as long as a trained student's; an untrained one is stuck
and reset every few steps), per teacher re-planning distance (0.3 m, the default, and 0: at every
state) and thread count; the first --warmup steps (worlds built, kernels compiled) are not counted.
A thread count bounds torch and numba (`vid2sim.threads.thread_pools`, `DistillConfig.threads`).
Per round (`DistillConfig.steps_per_round` env steps and `updates_per_round` updates): the
CPU-seconds each part costs, so a training's cost is the rounds times their sum.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np  # noqa: E402
import torch  # noqa: E402
from common import Run, add_run_args, cpu_seconds  # noqa: E402
from street_registry import build  # noqa: E402

from vid2sim.threads import thread_pools  # noqa: E402
from vid2sim.training.config import DistillConfig, TrainConfig  # noqa: E402
from vid2sim.training.distill import (Batch, Collector, env_specs, fit, make_averaged,  # noqa: E402
                                      make_optimizer, make_student)
from vid2sim.training.sac import make_vec_env, resolve_scenes  # noqa: E402
from vid2sim.training.student import StudentPolicy  # noqa: E402

IMAGE_SHAPE, VECTOR_SHAPE = (6, 3, 72, 128), (6, 2)  # the envs' observation: 6 stacked frames, 6 goal vectors


def measure_fit(threads: int, channels_last: bool, updates: int, seed: int = 0) -> dict:
    """CPU and wall seconds of `updates` learner steps of a fresh default student."""
    d = replace(DistillConfig(), updates_per_round=updates)
    student = StudentPolicy(d.student, IMAGE_SHAPE, VECTOR_SHAPE)
    if not channels_last:
        student.encoder.to(memory_format=torch.contiguous_format)
    rng = np.random.default_rng(seed)
    n = 4 * d.batch_size
    data = Batch(rng.integers(0, 256, (n, *student.input_shape), dtype=np.uint8),
                 rng.normal(size=(n, *VECTOR_SHAPE)).astype(np.float32),
                 rng.uniform(-1, 1, (n, 2)).astype(np.float32))
    optimizer, averaged = make_optimizer(student, d), make_averaged(student, d.ema_decay)
    with thread_pools(threads):
        fit(student, optimizer, data, replace(d, updates_per_round=5), rng, averaged)  # warm-up
        cpu0, t0 = cpu_seconds(), time.perf_counter()
        fit(student, optimizer, data, d, rng, averaged)
        cpu, wall = cpu_seconds() - cpu0, time.perf_counter() - t0
    samples = updates * d.batch_size
    return {"samples_per_cpu_s": samples / cpu, "samples_per_s": samples / wall,
            "round_cpu_s": DistillConfig().updates_per_round * d.batch_size * cpu / samples}


def measure_collection(config: TrainConfig, threads_list: list[int], steps: int, warmup: int) -> dict[int, dict]:
    """Per thread count: CPU and wall seconds per env step of the collection, the teacher driving
    (long episodes, as a trained student's; an untrained one is stuck and reset every few steps)."""
    env = make_vec_env(env_specs(config), 0)
    try:
        student = make_student(config, env)
        collector = Collector(env, student, config.seed)
        out = {}
        for threads in threads_list:
            with thread_pools(threads):
                collector.collect(warmup, 1.0, True)
                cpu0, t0 = cpu_seconds(), time.perf_counter()
                _, stats = collector.collect(steps, 1.0, True)
                cpu, wall = cpu_seconds() - cpu0, time.perf_counter() - t0
            out[threads] = {"steps_per_cpu_s": stats.steps / cpu, "steps_per_s": stats.steps / wall,
                            "round_cpu_s": DistillConfig().steps_per_round * cpu / stats.steps}
        return out
    finally:
        env.close()


def train_config(args, replan: float) -> TrainConfig:
    reg = build(args.root, list(range(1, args.streets + 1)), vary=True).root
    config = TrainConfig(run_dir=str(args.root / "distill_cost"), total_steps=args.steps, registry=str(reg),
                         n_envs=args.envs, n_actors=0, seed=0, method="distill", stuck_steps=10,
                         env_kwargs={"training": True, "checkout_root": str(args.root / "checkouts"),
                                     "fidelity": "exact"},
                         distill=replace(DistillConfig(), teacher_replan=replan))
    config.scene_ids = resolve_scenes(config)  # the split's training streets
    return config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--root", type=Path, default=Path("/tmp/vid2sim-distill"))
    ap.add_argument("--streets", type=int, default=40, help="varied streets in the registry (20 %% held out)")
    ap.add_argument("--envs", type=int, default=8)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--updates", type=int, default=100, help="fit: learner steps measured per setting")
    ap.add_argument("--steps", type=int, default=2000, help="collection: env steps measured per setting")
    ap.add_argument("--warmup", type=int, default=400, help="collection: env steps before measuring")
    ap.add_argument("--replan", type=float, nargs="+", default=[0.3, 0.0], help="teacher re-planning distances, m")
    ap.add_argument("--quick", action="store_true", help="6 streets, 10 updates, 80 steps")
    add_run_args(ap)
    args = ap.parse_args()
    if args.quick:
        args.streets, args.updates, args.steps, args.warmup, args.replan = 6, 10, 80, 16, [0.3]
    with Run("distill_cost", args) as run:
        print("fit (default student, batch 128):")
        for threads in args.threads:
            for layout in ("channels_last", "contiguous"):
                m = measure_fit(threads, layout == "channels_last", args.updates)
                run.record_all(f"fit {layout}, {threads} threads", m, {"samples_per_cpu_s": "samples/CPU-s",
                                                                      "samples_per_s": "samples/s",
                                                                      "round_cpu_s": "CPU-s"})
                print(f"  {layout:13s} {threads} threads: {m['samples_per_cpu_s']:6.0f} samples/CPU-s "
                      f"{m['samples_per_s']:6.0f} samples/s, {m['round_cpu_s']:5.1f} CPU-s per round", flush=True)
        print(f"collection ({args.envs} envs, exact render, the teacher driving):")
        for replan in args.replan:
            for threads, m in measure_collection(train_config(args, replan), args.threads, args.steps,
                                                 args.warmup).items():
                run.record_all(f"collection replan {replan} m, {threads} threads", m,
                               {"steps_per_cpu_s": "steps/CPU-s", "steps_per_s": "steps/s", "round_cpu_s": "CPU-s"})
                print(f"  replan {replan} m, {threads} threads: {m['steps_per_cpu_s']:5.1f} steps/CPU-s "
                      f"{m['steps_per_s']:5.1f} steps/s, {m['round_cpu_s']:5.1f} CPU-s per round", flush=True)


if __name__ == "__main__":
    main()
