"""Scene-count study: how held-out success grows with the number of training scenes.

For every count N and seed s: train (SAC, or the distilled pixel student with `method="distill"`)
on the registry split's nested train subset of size N (train-1 within train-5 within ...; the
registry provides them), then evaluate on the split's held-out test scenes. Each (N, s) training +
evaluation is one Ray task (`num_cpus` each), so a cluster runs them side by side. A count larger
than the train pool is refused (`StudyError`, named) before any run starts; `StudyConfig`'s numeric
fields are checked when it is built (`RangeError`, `vid2sim.ranges`). Scene checkouts and their sim-ready sets are
shared by all runs (OUT/checkouts). Output: `study.json`, a table, and `study.png` (SR and SPL
against N: mean over seeds, the seeds' spread, and the pooled 95 % bootstrap interval).

A finished (N, s) run leaves OUT/nN_sS/study_row.json with its training and evaluation settings;
a study run again over the same folder reuses every run whose settings are unchanged and trains
only the others, so an interrupted study goes on where it stopped. study.json and study.png cover
every finished run of the folder made with the study's settings, whichever invocation trained it
(studies that add seeds or counts beside finished runs build one table); `report_study` writes
them from the finished runs alone, training nothing.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Optional

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import ray  # noqa: E402

from vid2sim.ranges import checked  # noqa: E402
from vid2sim.registry import Registry  # noqa: E402
from vid2sim.training.config import DistillConfig, SACConfig, TrainConfig  # noqa: E402
from vid2sim.training.distill import train_distill  # noqa: E402
from vid2sim.training.evaluate import EvalConfig, bootstrap_ci, evaluate  # noqa: E402
from vid2sim.training.sac import train  # noqa: E402


class StudyError(ValueError):
    """A study that cannot run as asked (named reason first)."""


@checked
@dataclass
class StudyConfig:
    registry: str
    out_dir: str
    counts: list[int]
    seeds: int = 2  # trainings per count: seeds first_seed .. first_seed + seeds - 1
    first_seed: int = 0
    split_seed: int = 0
    total_steps: int = 20_000  # env steps per training
    n_envs: int = 2
    trials: int = 25
    obstacles: str = "static"
    env_kwargs: dict = field(default_factory=dict)
    sac: SACConfig = field(default_factory=SACConfig)
    num_cpus_per_run: float = 1.0
    env_id: str = "vid2sim/PointNav-v0"  # or PRIVILEGED_ID (goal vector + ranges, no pixels)
    env_module: str = "vid2sim.envs"
    eval_max_steps: Optional[int] = None  # evaluation episode limit (None: the env's 3000)
    method: str = "sac"  # "sac" or "distill" (TrainConfig.method)
    distill: DistillConfig = field(default_factory=DistillConfig)
    n_actors: int = 0  # Ray actors per training (0: its envs run inside the training's task)
    stuck_steps: Optional[int] = None  # training only: end episodes without motion (distill default: 10)


@dataclass
class StudyRow:
    count: int
    seed: int
    run_dir: str
    scene_ids: list[str]
    sr: float
    spl: float
    cost: float
    train_steps: int
    train_wall_s: float
    success: list[float] = field(default_factory=list)  # per held-out episode (for pooled intervals)


def check_counts(counts: list[int], available: int) -> list[int]:
    """Counts deduplicated and sorted; `StudyError` for a count < 1 or larger than the train pool."""
    bad = [c for c in counts if c < 1 or c > available]
    if bad:
        raise StudyError(f"bad_count: training-scene counts {bad} are outside 1..{available} (the registry split's "
                         f"train pool holds {available} scenes)")
    return sorted(set(counts))


ROW_NAME = "study_row.json"  # a finished run's row and the settings that made it


def run_settings(config: StudyConfig, count: int, seed: int,
                 scene_ids: list[str]) -> tuple[TrainConfig, EvalConfig, dict]:
    """The training and evaluation configs of run (count, seed) and the settings its row records."""
    run_dir = Path(config.out_dir) / f"n{count}_s{seed}"
    checkouts = str(Path(config.out_dir) / "checkouts")
    tc = TrainConfig(run_dir=str(run_dir), total_steps=config.total_steps, registry=config.registry,
                     env_id=config.env_id, env_module=config.env_module,
                     split_seed=config.split_seed, train_scenes=count, scene_ids=list(scene_ids),
                     n_envs=config.n_envs, n_actors=config.n_actors, seed=seed,
                     env_kwargs={"checkout_root": checkouts, **config.env_kwargs},
                     checkpoint_every=max(config.total_steps, 1), sac=config.sac, method=config.method,
                     distill=config.distill, stuck_steps=config.stuck_steps)
    ec = EvalConfig(registry=config.registry, policy=str(run_dir), split_seed=config.split_seed,
                    trials=config.trials, obstacles=config.obstacles,
                    env_id=None if config.method == "distill" else config.env_id,
                    max_steps=config.eval_max_steps, checkout_root=checkouts)
    return tc, ec, json.loads(json.dumps({"train": asdict(tc), "eval": asdict(ec)}))  # as stored (tuples -> lists)


def run_one(config: StudyConfig, count: int, seed: int, scene_ids: list[str]) -> StudyRow:
    """Train on `scene_ids` with `seed`, then evaluate on the held-out test scenes (or reuse the
    run's recorded row when its settings are unchanged)."""
    tc, ec, settings = run_settings(config, count, seed, scene_ids)
    run_dir = Path(tc.run_dir)
    done = finished_row(run_dir, settings)
    if done is not None:
        return done
    (run_dir / ROW_NAME).unlink(missing_ok=True)  # a run redone with other settings: its old row goes first
    result = train_distill(tc) if config.method == "distill" else train(tc, progress_bar=False)
    report = evaluate(ec)
    (run_dir / "eval.json").write_text(report.to_json())
    m = report.metrics
    success = [float(r["success"]) for r in report.records]
    row = StudyRow(count, seed, str(run_dir), list(scene_ids), m["sr"].mean, m["spl"].mean, m["cost"].mean,
                   result.num_timesteps, result.wall_s, success)
    (run_dir / ROW_NAME).write_text(json.dumps({"settings": settings, "row": asdict(row)}, indent=2))
    return row


def finished_row(run_dir: Path, settings: dict) -> Optional[StudyRow]:
    """The row a finished run recorded with exactly these settings, else None (the run is redone)."""
    path = run_dir / ROW_NAME
    if not path.is_file():
        return None
    recorded = json.loads(path.read_text())
    return StudyRow(**recorded["row"]) if recorded.get("settings") == settings else None


_run_remote = ray.remote(run_one)


def study_runs(config: StudyConfig, counts: list[int]) -> list[tuple[int, int]]:
    """The (count, seed) trainings of a study: every count with seeds first_seed .. first_seed + seeds - 1
    (a later study over the same folder with other seeds adds runs beside the finished ones)."""
    seeds = range(config.first_seed, config.first_seed + config.seeds)
    return [(n, s) for n in counts for s in seeds]


def run_study(config: StudyConfig) -> list[StudyRow]:
    """All (count, seed) runs as Ray tasks (needs `ray.init`); writes study.json and study.png over
    every finished run of the folder with the study's settings, and returns those rows."""
    Path(config.out_dir).mkdir(parents=True, exist_ok=True)
    pool = training_pool(config)
    counts = check_counts(config.counts, len(pool))
    remote = _run_remote.options(num_cpus=config.num_cpus_per_run)
    futures = [remote.remote(config, n, s, pool[:n]) for n, s in study_runs(config, counts)]
    asked = ray.get(futures)
    return write_summary(config, merge_rows(asked, finished_rows(config, pool)))


def training_pool(config: StudyConfig) -> list[str]:
    """The split's training scenes in subset order: the n-scene training set is the first n."""
    return Registry(config.registry).split(seed=config.split_seed).train


def report_study(config: StudyConfig) -> list[StudyRow]:
    """study.json and study.png from the folder's finished runs with the study's settings, training
    nothing (`StudyError` when there is none); returns their rows."""
    rows = finished_rows(config, training_pool(config))
    if not rows:
        raise StudyError(f"no_finished_runs: {config.out_dir} holds no finished run (nN_sS/{ROW_NAME}) made with "
                         "these study settings")
    return write_summary(config, rows)


RUN_FOLDER = re.compile(r"n(\d+)_s(\d+)")


def finished_rows(config: StudyConfig, pool: list[str]) -> list[StudyRow]:
    """Every run of the study folder (nN_sS, any count up to the training pool's size, any seed) that
    finished with exactly the settings this study would give it, by count then seed."""
    out = Path(config.out_dir)
    found = sorted((int(m.group(1)), int(m.group(2))) for d in out.glob("n*_s*")
                   if d.is_dir() and (m := RUN_FOLDER.fullmatch(d.name)))
    rows = []
    for n, s in found:
        if 1 <= n <= len(pool):
            _, _, settings = run_settings(config, n, s, pool[:n])
            if (row := finished_row(out / f"n{n}_s{s}", settings)) is not None:
                rows.append(row)
    return rows


def merge_rows(first: list[StudyRow], more: list[StudyRow]) -> list[StudyRow]:
    """`first` and the rows of `more` whose (count, seed) it lacks, by count then seed."""
    rows = {(r.count, r.seed): r for r in more} | {(r.count, r.seed): r for r in first}
    return [rows[k] for k in sorted(rows)]


def write_summary(config: StudyConfig, rows: list[StudyRow]) -> list[StudyRow]:
    """study.json (settings, rows, per-count aggregate) and study.png for `rows`; returns them."""
    out = Path(config.out_dir)
    counts = sorted({r.count for r in rows})
    test = Registry(config.registry).split(seed=config.split_seed).test
    summary = {"config": asdict(config), "counts": counts, "test_scenes": test,
               "rows": [asdict(r) for r in rows], "aggregate": aggregate(rows)}
    (out / "study.json").write_text(json.dumps(summary, indent=2))
    plot(rows, out / "study.png", config)
    return rows


def aggregate(rows: list[StudyRow]) -> dict[str, dict[str, float]]:
    """Per count: mean and std over seeds of SR and SPL, and SR's 95 % bootstrap interval over the
    pooled held-out episodes of all seeds (when the rows carry them)."""
    out = {}
    for n in sorted({r.count for r in rows}):
        sel = [r for r in rows if r.count == n]
        out[str(n)] = {"sr_mean": float(np.mean([r.sr for r in sel])), "sr_std": float(np.std([r.sr for r in sel])),
                       "spl_mean": float(np.mean([r.spl for r in sel])),
                       "spl_std": float(np.std([r.spl for r in sel])), "seeds": len(sel)}
        pooled = np.array([s for r in sel for s in r.success], float)
        if len(pooled):
            ci = bootstrap_ci(pooled)
            out[str(n)].update(sr_ci_low=ci.low, sr_ci_high=ci.high, episodes=len(pooled))
    return out


def plot(rows: list[StudyRow], path: Path, config: Optional[StudyConfig] = None) -> Path:
    agg = aggregate(rows)
    counts = [int(n) for n in agg]
    fig, axes = plt.subplots(1, 2, figsize=(8, 3.2))
    for ax, key, label in zip(axes, ("sr", "spl"), ("success rate", "SPL")):
        for r in rows:
            ax.plot(r.count, getattr(r, key), "o", color="0.7", ms=4)
        ax.errorbar(counts, [agg[str(n)][f"{key}_mean"] for n in counts],
                    yerr=[agg[str(n)][f"{key}_std"] for n in counts], marker="s", capsize=4,
                    label="mean +- std over seeds")
        if key == "sr" and all("sr_ci_low" in agg[str(n)] for n in counts):
            ax.fill_between(counts, [agg[str(n)]["sr_ci_low"] for n in counts],
                            [agg[str(n)]["sr_ci_high"] for n in counts], alpha=0.2,
                            label="95 % CI, pooled episodes")
            ax.legend(fontsize=7, loc="lower right")
        ax.set_xlabel("training scenes")
        ax.set_ylabel(label)
        ax.set_ylim(-0.05, 1.05)
    if config:
        seeds = sorted({int(a["seeds"]) for a in agg.values()})
        per_count = f"{seeds[0]}" if len(seeds) == 1 else f"{seeds[0]}-{seeds[-1]}"
        fig.suptitle(f"{config.total_steps} env steps per run, {per_count} seeds per count, "
                     f"{config.trials} trials/test scene", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path

