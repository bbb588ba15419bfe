"""Navigation metrics per episode and aggregated: SR, SPL, Cost, SNS (+ a proximity-aware SNS).

- SR: fraction of successful episodes (Anderson et al. 2018).
- SPL (Batra et al. 2020, "ObjectNav revisited", eq. 1): S x l / max(p, l), l = shortest
  geodesic start-goal length, p = length actually travelled. (The official Vid2Sim evaluation
  computes "SPL" as collision rate x success, which is not SPL.)
- Cost: collision events per episode (a contact after a step without one = one event), as the
  official Vid2Sim evaluation counts hits.
- SNS: the social navigation score as MetaUrban's released evaluation code computes it
  (github.com/metadriverse/metaurban; Wu et al., "MetaUrban", ICLR 2025): mean over episodes of
  1 - (steps in collision) / (episode length).
- Outcomes: how episodes end, time-outs split into "pinned" (the robot spent at least half the
  episode's steps in contact: pressed against the mesh or an obstacle, which a robot that cannot
  reverse does not leave) and "timeout" (it was still free to move).
- SNS-proximity (documented second figure): as SNS, but a step also counts against the score
  when the robot is within `proximity_radius` (0.2 m, MetaUrban project page) of a pedestrian;
  the MetaUrban authors state the paper's SNS was not the released one (MetaUrban GitHub issue #18).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, fields
from typing import Sequence

import numpy as np

from vid2sim.envs.reward import TIMEOUT

PINNED = "pinned"


@dataclass(frozen=True)
class EpisodeRecord:
    success: bool
    shortest_length: float  # m, A* geodesic start -> goal
    path_length: float  # m actually travelled
    collision_events: int
    collision_steps: int  # control steps with a contact
    proximity_steps: int  # control steps within the proximity radius of a pedestrian (no contact)
    steps: int
    end: str = ""
    # where it happened, in the scene frame (m, rad): empty in records written before they were kept
    start_pose: tuple[float, ...] = ()  # (x, y, yaw) at reset
    goal: tuple[float, ...] = ()  # (x, y)
    end_pose: tuple[float, ...] = ()  # (x, y, yaw) at the last step

    @classmethod
    def from_row(cls, row: dict) -> "EpisodeRecord":
        """The record in one row of a saved evaluation report (other keys, e.g. scene_id, ignored)."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in row.items() if k in names})


def spl(e: EpisodeRecord) -> float:
    """Batra et al.: S x l / max(p, l)."""
    if not e.success:
        return 0.0
    return e.shortest_length / max(e.path_length, e.shortest_length, 1e-9)


def sns(e: EpisodeRecord) -> float:
    """MetaUrban released SNS term of one episode: 1 - collision steps / steps."""
    return 1.0 - e.collision_steps / max(e.steps, 1)


def sns_proximity(e: EpisodeRecord) -> float:
    """Proximity-aware variant: collision or near-pedestrian steps count against the score."""
    return 1.0 - min(e.collision_steps + e.proximity_steps, e.steps) / max(e.steps, 1)


@dataclass(frozen=True)
class Summary:
    episodes: int
    sr: float
    spl: float
    cost: float
    sns: float
    sns_proximity: float


def summarize(records: Sequence[EpisodeRecord]) -> Summary:
    """Means over episodes (NaN for an empty list)."""
    if not records:
        nan = float("nan")
        return Summary(0, nan, nan, nan, nan, nan)
    m = lambda xs: float(np.mean(list(xs)))  # noqa: E731
    return Summary(len(records), m(e.success for e in records), m(spl(e) for e in records),
                   m(e.collision_events for e in records), m(sns(e) for e in records),
                   m(sns_proximity(e) for e in records))


def outcome(e: EpisodeRecord) -> str:
    """How the episode ended: "success", the env's failure end, or for a time-out "pinned" when at
    least half its steps were in contact (else "timeout")."""
    if e.success:
        return "success"
    if e.end == TIMEOUT and 2 * e.collision_steps >= e.steps:
        return PINNED
    return e.end or "unknown"


def outcomes(records: Sequence[EpisodeRecord]) -> dict[str, int]:
    """Episodes per `outcome`, most frequent first."""
    return dict(Counter(outcome(e) for e in records).most_common())
