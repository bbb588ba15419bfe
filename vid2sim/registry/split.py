"""Deterministic, leak-free train/test splits over registry scenes.

Leak-free: all clips of one source video (`source_group`) fall on one side. Groups are ordered
by sha256(seed, group), so the held-out test set for a seed is stable as scenes are added to
other groups. The train pool is ordered round-robin over groups (each group's scenes in
sha256(seed, scene) order), and train subsets are prefixes of that order: train-1 within train-5
within train-15 ..., each spanning as many source videos as possible.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass, field
from typing import Optional, Sequence

from vid2sim.ranges import checked
from vid2sim.registry.records import ACTIVE, SceneRecord


class SplitError(ValueError):
    """The requested split cannot be made from the selected scenes."""


@checked
@dataclass
class SplitConfig:
    seed: int = 0
    test_fraction: float = 0.2  # of scenes (whole groups are taken until reached)
    test_groups: Optional[tuple[str, ...]] = None  # fixed held-out groups (overrides fraction)
    train_sizes: tuple[int, ...] = ()  # nested subsets, e.g. (1, 5, 15)
    tags: tuple[str, ...] = ()  # scenes must carry all of these tags
    min_metrics: dict[str, float] = field(default_factory=dict)  # metric -> minimum value


@dataclass
class Split:
    seed: int
    registry_version: int
    train: list[str]  # ordered: train_subsets[k] == train[:k]
    test: list[str]
    train_groups: list[str]
    test_groups: list[str]
    train_subsets: dict[int, list[str]]
    versions: dict[str, int]  # scene_id -> version used
    config: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["train_subsets"] = {str(k): v for k, v in self.train_subsets.items()}
        return d


def _key(seed: int, name: str) -> str:
    return hashlib.sha256(f"{seed}\x00{name}".encode()).hexdigest()


def select(records: Sequence[SceneRecord], tags: Sequence[str], min_metrics: dict[str, float]) -> list[SceneRecord]:
    """Active scenes carrying every tag and meeting every metric minimum (missing metric = excluded)."""
    out = []
    for r in records:
        if r.status != ACTIVE or not set(tags) <= set(r.tags):
            continue
        ok = True
        for name, lo in min_metrics.items():
            v = r.metrics.get(name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or math.isnan(v) or v < lo:
                ok = False
                break
        if ok:
            out.append(r)
    return out


def _pick_test_groups(groups: dict[str, list[SceneRecord]], conf: SplitConfig) -> list[str]:
    if conf.test_groups is not None:
        unknown = sorted(set(conf.test_groups) - set(groups))
        if unknown:
            raise SplitError(f"test group(s) not among the selected scenes: {', '.join(unknown)}")
        return sorted(conf.test_groups)
    if not 0 <= conf.test_fraction < 1:
        raise SplitError(f"test_fraction must be in [0, 1), got {conf.test_fraction}")
    total = sum(len(v) for v in groups.values())
    want = round(conf.test_fraction * total)
    if conf.test_fraction > 0 and len(groups) >= 2:
        want = max(want, 1)
    picked, n = [], 0
    for g in sorted(groups, key=lambda g: _key(conf.seed, g)):
        if n >= want or len(picked) == len(groups) - 1:
            break
        picked.append(g)
        n += len(groups[g])
    return sorted(picked)


def _train_order(groups: dict[str, list[SceneRecord]], names: list[str], seed: int) -> list[str]:
    queues = [sorted((r.scene_id for r in groups[g]), key=lambda s: _key(seed, s))
              for g in sorted(names, key=lambda g: _key(seed, g))]
    order: list[str] = []
    while any(queues):
        for q in queues:
            if q:
                order.append(q.pop(0))
    return order


def make_split(records: Sequence[SceneRecord], conf: SplitConfig, registry_version: int) -> Split:
    """Split the latest scene records per `conf` (see module docstring)."""
    chosen = select(records, conf.tags, conf.min_metrics)
    if not chosen:
        raise SplitError("no active scenes match the tag/metric filters")
    groups: dict[str, list[SceneRecord]] = {}
    for r in chosen:
        groups.setdefault(r.source_group, []).append(r)
    test_groups = _pick_test_groups(groups, conf)
    train_groups = sorted(set(groups) - set(test_groups))
    train = _train_order(groups, train_groups, conf.seed)
    test = sorted(r.scene_id for g in test_groups for r in groups[g])
    too_big = [k for k in conf.train_sizes if k > len(train) or k < 1]
    if too_big:
        raise SplitError(f"train size(s) {too_big} not possible: {len(train)} train scenes available")
    used = set(train) | set(test)
    return Split(seed=conf.seed, registry_version=registry_version, train=train, test=test,
                 train_groups=train_groups, test_groups=test_groups,
                 train_subsets={k: train[:k] for k in sorted(conf.train_sizes)},
                 versions={r.scene_id: r.version for r in chosen if r.scene_id in used},
                 config=asdict(conf))
