"""What a factory step is: a name, an `Inputs` record, an `Outputs` record, a config picked
from the pipeline config, and `work(conf, inputs) -> StageWork`: the parts of its cache key and
the work that fills its folder and returns the summary for its marker.

An `Inputs` record's fields are named after the steps whose `Outputs` they are (`clip`: the
clip spec itself); an `Outputs` record is the step's finished folder with a property per file
it writes. The runner (`runtime/runner.py`) runs the work unless the folder's marker holds the
same cache key, writes the marker, then runs the step's optional `check(conf, outputs)`: a
verdict on the finished folder that writes nothing (the walkable step's corridor gate).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Callable, TypeVar

from vid2sim.factory.runtime.stage_cache import StageWork, input_key

CLIP = "clip"  # the Inputs field that takes the clip spec rather than a step's outputs
Out = TypeVar("Out", bound="StepOutputs")


@dataclass(frozen=True)
class StepOutputs:
    """A step's output folder (absolute, or relative to the clip folder while it travels)."""

    dir: Path

    @property
    def key(self) -> str:
        """Cache key of the folder: its marker key (content hash for a folder made elsewhere)."""
        return input_key(self.dir)

    def under(self: Out, root: Path) -> Out:
        """The record with `dir` resolved against `root` (an absolute `dir` stays)."""
        return replace(self, dir=Path(root) / self.dir)

    def relative_to(self: Out, root: Path) -> Out:
        """The record with `dir` relative to `root` (a folder outside `root` stays absolute)."""
        d = Path(self.dir)
        return replace(self, dir=d.relative_to(root) if d.is_relative_to(root) else d)


def passes(conf: Any, out: StepOutputs) -> None:
    """The check of a step without one."""


@dataclass(frozen=True)
class Step:
    """One factory step; `configure(pipeline_conf, job)` gives the config `work` takes."""

    name: str
    version: int  # the stage code's STAGE_VERSION, part of its cache key
    inputs: type
    outputs: type
    configure: Callable[[Any, Any], Any]
    work: Callable[[Any, Any], StageWork]
    check: Callable[[Any, Any], None] = passes  # raises StageError to fail the clip; writes nothing

    def upstream(self) -> tuple[str, ...]:
        """Names of the steps whose outputs this step reads."""
        return tuple(f.name for f in fields(self.inputs) if f.name != CLIP)

    def required(self) -> tuple[str, ...]:
        """The upstream steps without which it cannot run (an optional input defaults to None)."""
        return tuple(f.name for f in fields(self.inputs) if f.name != CLIP and f.default is not None)


def step(module: Any) -> Step:
    """The Step a step module declares (NAME, VERSION, Inputs, Outputs, configure, work and
    optionally check)."""
    return Step(module.NAME, module.VERSION, module.Inputs, module.Outputs, module.configure, module.work,
                getattr(module, "check", passes))
