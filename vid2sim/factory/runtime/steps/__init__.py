"""The factory's steps, in order: one module each (Inputs, Outputs, configure, main).

`STEPS` is the one list of stages: the pipeline runs it, the work store stages its folders,
progress shows it, and docs/architecture.md's table is checked against it.
"""

from __future__ import annotations

from vid2sim.factory.runtime.steps import bundle, decode, masks, meshing, metric, recon, sfm, walkable
from vid2sim.factory.runtime.steps.base import Step, step

STEPS: tuple[Step, ...] = tuple(step(m) for m in (decode, masks, sfm, metric, recon, meshing, walkable, bundle))
STEP_NAMES: tuple[str, ...] = tuple(s.name for s in STEPS)
