"""The factory's typed steps: one list of stages, records and docs that agree, one runner.

- `steps.STEPS` and the stage table of docs/architecture.md (and docs/factory.md, the data-flow
  line, the README list) name the same stages in the same order; the table's inputs are the
  `Inputs` records' fields and its "writes" cell names every file of the `Outputs` record.
- Every `Inputs` field is an earlier step's `Outputs` record (or the clip spec).
- Through the runner, decode -> masks on a small panning clip: the marker is the newest file of
  each folder; an unchanged re-run rewrites no marker; a changed config or bumped version reruns
  exactly that step and the ones after it.
"""

from __future__ import annotations

import re
import typing
from dataclasses import fields, is_dataclass, replace
from pathlib import Path

import cv2
import pytest

from ingest_media import panning_frames
from vid2sim.factory.ingest import decode as decode_stage
from vid2sim.factory.ingest.clips import ClipSpec
from vid2sim.factory.ingest.sources import Source, resolve_source
from vid2sim.factory.runtime.config import ClipJob, preset
from vid2sim.factory.runtime.runner import ClipWork, clip_work, run_step
from vid2sim.factory.runtime.stage_cache import MARKER, StageError, load_record
from vid2sim.factory.runtime.steps import STEP_NAMES, STEPS
from vid2sim.factory.runtime.steps.base import CLIP, Step, StepOutputs

ROOT = Path(__file__).resolve().parents[1]
BY_NAME = {s.name: s for s in STEPS}


def _table(doc: str, header: str) -> list[list[str]]:
    """Rows (cells) of the first markdown table after `header` in docs/<doc>."""
    text = (ROOT / "docs" / doc).read_text().split(header, 1)[1]
    rows = []
    for line in text.splitlines():
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
        elif rows:
            break
    return [r for r in rows[1:] if not set(r[0]) <= set("-")]


def _files(step: Step) -> dict[str, str]:
    """{property: path relative to the step folder} of every file its Outputs record names."""
    out = step.outputs(Path("STEP"))
    props = [n for n, v in vars(step.outputs).items() if isinstance(v, property)]
    return {n: getattr(out, n).relative_to("STEP").as_posix() for n in props
            if isinstance(getattr(out, n), Path)}


def test_the_stage_list_and_the_architecture_page_agree():
    rows = _table("architecture.md", "## Factory stages")
    assert [r[0] for r in rows] == list(STEP_NAMES)
    for row in rows:
        step = BY_NAME[row[0]]
        assert row[1].startswith(f"`factory/runtime/steps/{step.name}.py`")
        assert [re.sub(r" \(optional\)$", "", x.strip()) for x in row[2].split(",")] == \
            [f.name for f in fields(step.inputs)], f"{step.name}: inputs column vs its Inputs record"
        for prop, rel in _files(step).items():
            assert f"`{rel}" in row[4], f"{step.name}: {prop} ({rel}) is not in the writes column"


def test_the_other_pages_name_the_same_stages_in_order():
    assert [r[0].strip("`") for r in _table("factory.md", "## Stages")] == list(STEP_NAMES)
    flow = re.search(r"^ +(decode( -> \w+)+)$", (ROOT / "docs" / "architecture.md").read_text(), re.M)
    assert flow and flow.group(1).split(" -> ") == list(STEP_NAMES)
    readme = re.search(r"\*\*Factory stages\*\*: ([a-z, ]+);", (ROOT / "README.md").read_text())
    assert readme and readme.group(1).split(", ") == list(STEP_NAMES)


def test_every_step_is_typed_and_reads_only_earlier_steps():
    assert len(set(STEP_NAMES)) == len(STEP_NAMES)
    job = ClipJob(ClipSpec("c", Source("video", Path("v.mp4"), "v.mp4", "0" * 64), None, "g"), "s", "CC0")
    for i, step in enumerate(STEPS):
        assert is_dataclass(step.inputs) and is_dataclass(step.outputs)
        assert issubclass(step.outputs, StepOutputs) and _files(step)
        hints = typing.get_type_hints(step.inputs)
        for f in fields(step.inputs):
            if f.name == CLIP:
                assert hints[f.name] is ClipSpec
                continue
            assert f.name in STEP_NAMES[:i], f"{step.name} reads {f.name}, not an earlier step"
            assert BY_NAME[f.name].outputs in typing.get_args(hints[f.name]) + (hints[f.name],)
        for name in ("fast", "paper"):  # the named presets configure every step
            assert is_dataclass(step.configure(preset(name), job))
    assert {s.name for s in STEPS if not s.upstream()} == {"decode"}


# ----------------------------------------------------------------------------- the runner


def _frames(tmp_path: Path, n: int = 12) -> Path:
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(panning_frames(n, h=120, w=160, speed=3.0)):
        cv2.imwrite(str(folder / f"{i:03d}.png"), f)
    return folder


def _chain(work: ClipWork) -> dict[str, tuple[str, int]]:
    """decode -> masks through the runner; {step: (marker key, marker mtime_ns)}."""
    for name in ("decode", "masks"):
        work = run_step(BY_NAME[name], work)
    clip_dir = Path(work.workdir) / work.clip_id
    for out in work.outputs.values():  # the marker is the last file of each folder
        files = [p.stat().st_mtime_ns for p in (clip_dir / out.dir).rglob("*") if p.is_file() and p.name != MARKER]
        assert files and max(files) <= (clip_dir / out.dir / MARKER).stat().st_mtime_ns
    return {n: (load_record(clip_dir / o.dir).key, (clip_dir / o.dir / MARKER).stat().st_mtime_ns)
            for n, o in work.outputs.items()}


def test_the_runner_reruns_exactly_the_changed_step_and_those_after_it(tmp_path, monkeypatch):
    frames = _frames(tmp_path)
    job = ClipJob(ClipSpec("clip0", resolve_source(frames), None, "g"), "s", "CC0")
    conf = replace(preset("fast"), decode=decode_stage.DecodeConfig(workers=1, dup_flow_px=0.0))
    work = clip_work(job, conf, tmp_path / "work")
    first = _chain(work)
    assert set(first) == {"decode", "masks"} and _chain(work) == first
    masks2 = replace(conf, masks=replace(conf.masks, dilate_px=conf.masks.dilate_px + 2))
    second = _chain(replace(work, conf=masks2))
    assert {s for s in first if first[s] != second[s]} == {"masks"}
    monkeypatch.setattr(decode_stage, "STAGE_VERSION", decode_stage.STAGE_VERSION + 1)
    third = _chain(replace(work, conf=masks2))
    assert {s for s in first if second[s] != third[s]} == {"decode", "masks"}


def test_the_runner_names_a_missing_input(tmp_path):
    job = ClipJob(ClipSpec("clip0", resolve_source(_frames(tmp_path, 3)), None, "g"), "s", "CC0")
    with pytest.raises(StageError) as e:
        run_step(BY_NAME["sfm"], clip_work(job, preset("fast"), tmp_path / "work"))
    assert e.value.stage == "sfm" and e.value.reason == "missing_input" and "decode, masks" in e.value.detail
