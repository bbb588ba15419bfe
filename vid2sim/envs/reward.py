"""The paper's reward (appendix, "Reward shaping") and the episode end conditions.

R = R_term + c1 (d_{t-1} - d_t) - c2 |s_t - s_{t-1}| v_t - c3 1(collision at t) - c4
  R_term = +10 on success (within 0.5 m of the goal), -10 on failure (left the walkable area,
  more than 3 collision events) and -10 at the 3000-step limit.
The paper counts the step limit as a failure; we give the same -10 but report it as
`truncated` (not `terminated`) so that value bootstrapping stays correct.
s is the normalised steering action and v the normalised speed (both in [-1, 1] / [0, 1]).
"""

from __future__ import annotations

from dataclasses import dataclass

from vid2sim.envs.config import RewardConfig

SUCCESS, LEFT_WALKABLE, TOO_MANY_COLLISIONS, TIMEOUT = "success", "left_walkable", "collisions", "timeout"


@dataclass(frozen=True)
class StepOutcome:
    """What happened during one control step (inputs to the reward)."""

    prev_distance: float  # m to goal before the step
    distance: float  # m to goal after the step
    steer_change: float  # |s_t - s_{t-1}|, normalised units
    speed: float  # normalised speed command in [0, 1]
    collided: bool  # any contact during the step
    collision_events: int  # events so far in the episode (a new contact after none = 1 event)
    on_walkable: bool
    step: int  # steps taken so far (1 after the first step)


@dataclass(frozen=True)
class RewardTerms:
    terminal: float
    distance: float
    steer: float
    crash: float
    time: float
    end: str  # "" (running), SUCCESS, LEFT_WALKABLE, TOO_MANY_COLLISIONS or TIMEOUT

    @property
    def total(self) -> float:
        return self.terminal + self.distance + self.steer + self.crash + self.time

    @property
    def terminated(self) -> bool:
        return self.end in (SUCCESS, LEFT_WALKABLE, TOO_MANY_COLLISIONS)

    @property
    def truncated(self) -> bool:
        return self.end == TIMEOUT


def episode_end(o: StepOutcome, c: RewardConfig) -> str:
    """Why the episode ends after this step ("" = it goes on); success wins ties."""
    if o.distance <= c.success_radius:
        return SUCCESS
    if not o.on_walkable:
        return LEFT_WALKABLE
    if o.collision_events > c.max_collisions:
        return TOO_MANY_COLLISIONS
    if o.step >= c.max_steps:
        return TIMEOUT
    return ""


def reward(o: StepOutcome, c: RewardConfig) -> RewardTerms:
    end = episode_end(o, c)
    terminal = c.success if end == SUCCESS else (c.failure if end else 0.0)
    return RewardTerms(terminal=terminal,
                       distance=c.c_dist * (o.prev_distance - o.distance),
                       steer=-c.c_steer * o.steer_change * o.speed,
                       crash=-c.c_crash * float(o.collided),
                       time=-c.c_time, end=end)
