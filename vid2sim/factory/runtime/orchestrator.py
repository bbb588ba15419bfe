"""Run many clips through a chain of stages as Ray tasks.

The driver keeps one state machine per clip: when a clip's stage finishes, its
next stage is submitted; `ray.wait` multiplexes all clips, so clips advance
independently and a clip that fails stops alone. A stage takes the clip's state
(for the pipeline, `runner.ClipWork`) and returns its next state. Stage outputs are
cached (see `stage_cache.py`), so a re-run resumes after the last finished stage.
Ray retries a task whose worker died (`max_retries`); a StageError is a verdict about
the input and is not retried.

Besides its wall seconds, each stage reports `stats` (`ClipResult.stats[stage]`): the node it
ran on, the worker process's CPU seconds and the object-store transfers it made
(`staging.transfer_totals`, seconds / bytes / folders moved down, up and as a fetched source).
"""

from __future__ import annotations

import resource
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import ray

from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.factory.runtime.staging import transfer_totals


@dataclass(frozen=True)
class StageSpec:
    """One step of a clip's chain.

    `fn(state) -> state` runs inside a Ray worker: it takes the clip's state as the earlier
    stages left it and returns the next one. `num_cpus` / `num_gpus` are Ray's reservations.
    """

    name: str
    fn: Callable[[Any], Any]
    num_cpus: float = 1.0
    num_gpus: float = 0.0


@dataclass
class ClipState:
    clip_id: str
    work: Any
    stage_index: int = 0
    status: str = "pending"  # pending | running | done | failed
    stage: str = ""
    reason: str = ""
    detail: str = ""
    seconds: dict = field(default_factory=dict)
    started: float = 0.0
    stats: dict = field(default_factory=dict)  # stage -> node, CPU seconds, transfers (see module doc)


@dataclass(frozen=True)
class ClipResult:
    clip_id: str
    ok: bool
    failed_stage: str
    reason: str
    detail: str
    work: Any  # the clip's last state (None for a clip that never started)
    seconds: dict
    stats: dict = field(default_factory=dict)  # stage -> node, CPU seconds, transfers (see module doc)


def _cpu_seconds() -> float:
    """CPU seconds of this process and its reaped children (user + system)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _node_id() -> str:
    """The Ray node this process runs on ("" outside Ray: asking would start a runtime)."""
    if not ray.is_initialized():
        return ""
    try:
        return ray.get_runtime_context().get_node_id()
    except Exception:
        return ""


def _run_stage(fn: Callable[[Any], Any], stage_name: str, work: Any) -> dict:
    """Executed in a Ray worker: run the stage, turn errors into a verdict record."""
    t0, cpu0, moved0 = time.perf_counter(), _cpu_seconds(), transfer_totals()

    def done(**rec: Any) -> dict:
        moved = transfer_totals()
        stats = {"node": _node_id(), "cpu_s": _cpu_seconds() - cpu0,
                 **{k: v - moved0.get(k, 0) for k, v in moved.items()}}
        return {**rec, "seconds": time.perf_counter() - t0, "stats": stats}

    try:
        return done(ok=True, work=fn(work))
    except StageError as e:
        return done(ok=False, reason=e.reason, detail=e.detail or str(e))
    except Exception as e:  # a bug or an unexpected input: report, do not crash the batch
        tb = traceback.format_exc(limit=6)
        return done(ok=False, reason=f"error:{type(e).__name__}", detail=f"{e}\n{tb}")


def init_ray(address: Optional[str] = None, num_cpus: Optional[int] = None, attempts: int = 3,
             runtime_env: Optional[dict] = None) -> None:
    """The one way the project starts Ray (factory pipeline, training, benchmarks): connect to
    the cluster at `address`, or start an embedded local runtime with `num_cpus` CPUs (>= 1;
    None: all). Does nothing when Ray is already initialised in this process (`runtime_env` is
    then not applied). `runtime_env` (e.g. env_vars) goes to the workers.

    Retries a local start that times out, up to `attempts` tries in all: Ray waits a fixed 30 s
    for its raylet, and on a heavily loaded machine the first start can miss that window (the
    error says "node timed out during startup"); a retry usually succeeds. Other errors raise."""
    if num_cpus is not None and num_cpus < 1:
        raise ValueError(f"num_cpus={num_cpus}: the local Ray runtime needs at least 1 CPU")
    if ray.is_initialized():
        return
    for attempt in range(max(1, attempts)):
        try:
            if address:
                ray.init(address=address, ignore_reinit_error=True, log_to_driver=False,
                         runtime_env=runtime_env)
            else:
                ray.init(num_cpus=num_cpus, include_dashboard=False, ignore_reinit_error=True,
                         log_to_driver=False, configure_logging=False, runtime_env=runtime_env)
            return
        except Exception as e:  # Ray raises a bare Exception for the start-up timeout
            if "timed out during startup" not in str(e) or attempt >= attempts - 1:
                raise
            ray.shutdown()


ensure_ray = init_ray  # the earlier name of `init_ray`, kept for existing callers


def run_clips(
    clips: Sequence[tuple[str, Any]],
    stages: Sequence[StageSpec],
    *,
    max_retries: int = 2,
    on_update: Optional[Callable[[ClipState], None]] = None,
    on_clip_done: Optional[Callable[[ClipState], None]] = None,
) -> list[ClipResult]:
    """Push each (clip_id, state) through `stages`; returns one result per clip.

    `on_update` is called in the driver whenever a clip changes stage or status;
    `on_clip_done` when a clip finished all stages (e.g. to commit it), and may
    raise StageError to mark the clip failed at that point.
    """
    init_ray()  # a local runtime unless Ray is already initialised
    remote = ray.remote(_run_stage)
    states = {cid: ClipState(cid, work) for cid, work in clips}
    inflight: dict[ray.ObjectRef, str] = {}

    def submit(state: ClipState) -> None:
        spec = stages[state.stage_index]
        state.status, state.stage, state.started = "running", spec.name, time.perf_counter()
        ref = remote.options(num_cpus=spec.num_cpus, num_gpus=spec.num_gpus,
                             max_retries=max_retries, name=f"{spec.name}:{state.clip_id}"
                             ).remote(spec.fn, spec.name, state.work)
        inflight[ref] = state.clip_id
        if on_update:
            on_update(state)

    def fail(state: ClipState, reason: str, detail: str) -> None:
        state.status, state.reason, state.detail = "failed", reason, detail
        if on_update:
            on_update(state)

    for state in states.values():
        submit(state)
    while inflight:
        ready, _ = ray.wait(list(inflight), num_returns=1)
        state = states[inflight.pop(ready[0])]
        try:
            out = ray.get(ready[0])
        except Exception as e:  # worker died more often than max_retries, or similar
            fail(state, f"ray:{type(e).__name__}", str(e)[:2000])
            continue
        state.seconds[state.stage] = out["seconds"]
        state.stats[state.stage] = out.get("stats", {})
        if not out["ok"]:
            fail(state, out["reason"], out["detail"])
            continue
        state.work = out["work"]
        state.stage_index += 1
        if state.stage_index < len(stages):
            submit(state)
            continue
        try:
            state.stage = "commit"
            if on_clip_done:
                on_clip_done(state)
            state.status = "done"
            if on_update:
                on_update(state)
        except StageError as e:
            fail(state, e.reason, e.detail or str(e))
    return [ClipResult(s.clip_id, s.status == "done", s.stage if s.status == "failed" else "",
                       s.reason, s.detail, s.work, s.seconds, s.stats) for s in states.values()]
