"""Two policies on the same held-out episodes: the paired difference of a metric, with its interval.

Reads two `EvalReport`s (`vid2sim eval policy --out`, a study run's eval.json, ...) made with the
same episodes: the same registry, trial seeds, obstacle mode, pedestrians and episode limit
(trial k of scene s starts from seed + k, so both policies drove from the same start to the same
goal among the same obstacles). Episodes are paired by (scene, trial); only the pairs both
reports hold are compared. The difference B - A of a metric's mean over those episodes comes with
a 95 % percentile-bootstrap interval over episodes (resampling pairs, which keeps the episodes'
shared difficulty out of the interval), the share of resamples where B does not beat A, and for
success the discordant pairs (episodes one policy wins and the other loses).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vid2sim.envs.metrics import EpisodeRecord
from vid2sim.training.evaluate import EvalReport, Interval, bootstrap_means, episode_values

SAME_EPISODES = ("registry", "seed", "obstacles", "pedestrians", "max_steps")  # EvalConfig fields


class UnpairedReports(ValueError):
    """Two evaluation reports that did not drive the same episodes (named field first)."""


@dataclass
class PairedDifference:
    metric: str
    episodes: int  # pairs compared
    mean_a: float
    mean_b: float
    difference: Interval  # B - A, with its 95 % paired-bootstrap interval
    p_not_better: float  # share of resamples with B - A <= 0
    only_a: int  # success: episodes A wins and B loses (other metrics: A above B)
    only_b: int


def keyed_records(report: EvalReport) -> dict[tuple[str, int], EpisodeRecord]:
    """(scene, trial) -> episode; trial k is the k-th record of its scene (the order `evaluate` runs)."""
    out: dict[tuple[str, int], EpisodeRecord] = {}
    seen: dict[str, int] = {}
    for row in report.records:
        scene = row["scene_id"]
        k = seen.get(scene, 0)
        seen[scene] = k + 1
        out[(scene, k)] = EpisodeRecord.from_row(row)
    return out


def _plain(value):
    """A config value as JSON reads it back (tuples as lists), so saved and fresh reports compare."""
    return list(value) if isinstance(value, tuple) else value


def check_same_episodes(a: EvalReport, b: EvalReport) -> None:
    """`UnpairedReports` when a setting that decides the episodes differs between the reports."""
    for name in SAME_EPISODES:
        va, vb = a.config.get(name), b.config.get(name)
        if name == "pedestrians" and a.config.get("obstacles") != "dynamic":
            continue  # walkers only exist in SocialNav
        if _plain(va) != _plain(vb):
            raise UnpairedReports(f"{name}: the reports drove different episodes ({name} {va!r} against {vb!r})")


def paired_difference(a: EvalReport, b: EvalReport, metric: str = "sr", n: int = 10_000,
                      seed: int = 0) -> PairedDifference:
    """B - A of `metric` (sr, spl, cost, sns, sns_proximity) over the episodes both reports hold."""
    check_same_episodes(a, b)
    ra, rb = keyed_records(a), keyed_records(b)
    keys = sorted(ra.keys() & rb.keys())
    if not keys:
        raise UnpairedReports("episodes: the reports share no (scene, trial) episode")
    va = episode_values([ra[k] for k in keys])
    if metric not in va:
        raise UnpairedReports(f"metric: {metric!r} is not one of {', '.join(va)}")
    xa, xb = va[metric], episode_values([rb[k] for k in keys])[metric]  # [E], [E]
    d = xb - xa  # [E]
    means = bootstrap_means(d, n, seed)  # [n]
    lo, hi = np.quantile(means, [0.025, 0.975])
    return PairedDifference(metric, len(keys), float(xa.mean()), float(xb.mean()),
                            Interval(float(d.mean()), float(lo), float(hi)), float((means <= 0).mean()),
                            int((xa > xb).sum()), int((xb > xa).sum()))
