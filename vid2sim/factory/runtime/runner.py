"""The one runner of factory steps, for a local work folder and a work store alike, and the
only code that checks or writes a stage marker (`stage.json`).

`run_stage(work, out_dir)` runs one stage into a folder: it computes the cache key from the
stage's version, config and input keys (`stage_cache.stage_key`), skips the work when the
folder's marker holds that key, otherwise empties the folder (keeping a partial run the stage
resumes), runs the stage's work and writes the marker last. The CLI, tests and benchmarks call
it directly with a stage's `StageWork` (e.g. `run_stage(sfm.work(conf, images, masks), out)`).

`run_step(step, work)` runs one step of one clip:
1. on a work store (object-store URI): the clip's finished folders that the step may read
   (those of the steps done so far, and its own) are fetched into this node's scratch copy of
   the clip folder (`staging.py`), and a URI source is fetched by this node;
2. threads are limited to the task's CPUs;
3. the step's `Inputs` record is built from the `Outputs` of the steps done so far;
4. the step's work runs through `run_stage`, then its check (a verdict that writes nothing,
   also on a cached folder);
5. on a work store the step's folder is uploaded, marker last.
It returns the clip's work record with the step's `Outputs` added, the folder relative to the
clip folder, so the record is valid on every node.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Mapping

from vid2sim.factory.runtime.config import ClipJob, PipelineConfig
from vid2sim.factory.runtime.object_store import ObjectStore, is_remote
from vid2sim.factory.runtime.stage_cache import (MARKER, StageError, StageWork, Timer, fresh_dir, is_done,
                                                 mark_done, stage_key)
from vid2sim.factory.runtime.staging import fetch_from_store, local_clip_dir, localize_source, sync_down, sync_up
from vid2sim.factory.runtime.steps.base import CLIP, Step, StepOutputs
from vid2sim.factory.runtime.threads import limit_threads


@dataclass(frozen=True)
class ClipWork:
    """A clip on its way through the steps: what to make, with which config, where, and the
    outputs of the steps done so far (by step name)."""

    job: ClipJob
    conf: PipelineConfig
    workdir: str  # a local folder or an object-store URI; the clip's folder is <workdir>/<clip_id>
    cpus: float = 1.0  # CPUs a step may use when Ray assigned none
    outputs: Mapping[str, StepOutputs] = field(default_factory=dict)

    @property
    def clip_id(self) -> str:
        return self.job.spec.clip_id

    @property
    def on_store(self) -> bool:
        return is_remote(self.workdir)

    def with_output(self, name: str, out: StepOutputs) -> "ClipWork":
        return replace(self, outputs={**self.outputs, name: out})


def clip_work(job: ClipJob, conf: PipelineConfig, workdir: str | Path, cpus: float = 1.0,
              **outputs: StepOutputs) -> ClipWork:
    """A clip's starting record: a local work folder (made absolute) or a work store URI;
    `outputs` enter the chain past its start (e.g. `metric=` a clip posed elsewhere)."""
    where = str(workdir).rstrip("/") if is_remote(str(workdir)) else str(Path(workdir).resolve())
    return ClipWork(job, conf, where, cpus, outputs)


def cache_key(work: StageWork) -> str:
    """The stage run's cache key: its name, version, config and input keys."""
    return stage_key(work.stage, work.version, work.conf, *work.input_keys)


def run_stage(work: StageWork, out_dir: Path) -> Path:
    """Run one stage into `out_dir` unless its marker holds the run's key; the marker is
    written last, after the work returned (see module doc)."""
    out_dir, key = Path(out_dir), cache_key(work)
    if is_done(out_dir, key):
        return out_dir
    if out_dir.is_dir() and work.resume(out_dir):
        (out_dir / MARKER).unlink(missing_ok=True)
    else:
        fresh_dir(out_dir)
    try:
        with Timer() as t:
            summary = work.build(out_dir)
    except BaseException:
        if out_dir.is_dir() and not any(out_dir.iterdir()):  # failed before writing: no folder left
            out_dir.rmdir()
        raise
    mark_done(out_dir, work.stage, key, summary, t.seconds)
    return out_dir


def run_step(step: Step, work: ClipWork) -> ClipWork:
    """Run `step` on the clip (see module doc); returns the record with its outputs added."""
    if work.on_store:
        return work.with_output(step.name, _run_on_store(step, work))
    return work.with_output(step.name, _run(step, work, Path(work.workdir) / work.clip_id))


def _inputs(step: Step, work: ClipWork, clip_dir: Path) -> object:
    missing = [n for n in step.required() if n not in work.outputs]
    if missing:
        raise StageError(step.name, "missing_input", f"no outputs of {', '.join(missing)} for {work.clip_id}")
    names = [f.name for f in fields(step.inputs)]
    return step.inputs(**{n: work.job.spec if n == CLIP else work.outputs[n].under(clip_dir)
                          for n in names if n == CLIP or n in work.outputs})


def _run(step: Step, work: ClipWork, clip_dir: Path) -> StepOutputs:
    limit_threads(work.cpus)
    conf = step.configure(work.conf, work.job)
    todo = step.work(conf, _inputs(step, work, clip_dir))
    if todo.stage != step.name:
        raise StageError(step.name, "wrong_stage", f"the step's work is stage {todo.stage!r}")
    out = step.outputs(run_stage(todo, clip_dir / step.name))
    step.check(conf, out)
    return out.relative_to(clip_dir)


def _folders(work: ClipWork, name: str) -> tuple[str, ...]:
    """The clip folders a step may read on a store: those of the steps done so far, and its own."""
    rel = [Path(o.dir).parts[0] for o in work.outputs.values() if not Path(o.dir).is_absolute()]
    return tuple(dict.fromkeys([*rel, name]))


def _run_on_store(step: Step, work: ClipWork) -> StepOutputs:
    store, local = ObjectStore(work.workdir), local_clip_dir(work.workdir, work.clip_id)
    local.mkdir(parents=True, exist_ok=True)
    sync_down(store, work.clip_id, local, _folders(work, step.name))
    out = _run(step, replace(work, job=localize_source(work.job)), local)
    sync_up(store, work.clip_id, local, [Path(out.dir).parts[0]])
    return out


def local_outputs(work: ClipWork, name: str) -> StepOutputs:
    """A finished step's outputs as a local folder (fetched from the work store when there is one)."""
    out = work.outputs[name]
    if work.on_store:
        return replace(out, dir=fetch_from_store(work.workdir, work.clip_id, str(out.dir)))
    return out.under(Path(work.workdir) / work.clip_id)


class StepTask:
    """Picklable Ray task body: `StepTask(step)(work)` is `run_step(step, work)`."""

    def __init__(self, step: Step) -> None:
        self.step = step
        self.__name__ = step.name

    def __call__(self, work: ClipWork) -> ClipWork:
        return run_step(self.step, work)
