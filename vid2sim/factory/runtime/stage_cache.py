"""Stage convention: resumable, cached outputs under ONE cache rule.

A stage writes into its own folder; when it is finished, the runner (`runtime/runner.py`
`run_stage`, the only code that checks or writes a marker) adds an atomic `stage.json` marker
holding the stage name, the cache key and a summary, the last file of the folder. A folder
without the marker (a stage killed mid-way) is treated as not done and redone. A stage itself
only says what its run is (`StageWork`: the parts of its key and the work that fills the folder).

The cache rule (`stage_key`): key = hash(stage name, STAGE_VERSION, config, input keys).
Each stage module declares `STAGE_VERSION` and bumps it when its logic changes, so a re-run
after a fix redoes that stage and, through the input keys, every stage downstream of it.
An input's key (`input_key`) is the marker key of the stage output holding it, or a
content hash for a folder or file made outside the pipeline.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Optional

from vid2sim.versioning import code_version, config_hash, to_jsonable

MARKER = "stage.json"


class StageError(RuntimeError):
    """A stage could not produce its output; `reason` is a short machine-readable tag."""

    def __init__(self, stage: str, reason: str, detail: str = "") -> None:
        self.stage, self.reason, self.detail = stage, reason, detail
        super().__init__(f"[{stage}] {reason}" + (f": {detail}" if detail else ""))


@dataclass(frozen=True)
class StageRecord:
    """Contents of a finished stage's marker."""

    stage: str
    key: str
    summary: dict
    seconds: float
    code_version: str


def _no_partial_run(out_dir: Path) -> bool:
    return False


@dataclass(frozen=True)
class StageWork:
    """One run of a stage, before it runs: the parts of its cache key (`stage_key(stage, version,
    conf, *input_keys)`) and `build(out_dir)`, which fills the empty folder and returns the
    summary its marker records. `resume(out_dir)`: the folder holds a partial run of this very
    key that `build` continues (the runner then keeps it)."""

    stage: str
    version: int
    conf: Any
    input_keys: tuple[Any, ...]
    build: Callable[[Path], dict]
    resume: Callable[[Path], bool] = _no_partial_run


def stage_key(stage: str, version: int, conf: Any, *input_keys: Any) -> str:
    """THE cache rule: key of a stage run = its name, code version, config and input keys."""
    return config_hash(stage, int(version), conf, list(input_keys))


def input_key(path: Path) -> str:
    """Key of a stage input: the marker key of the stage output at `path` (or of its parent
    folder, for a sub-folder such as `decode/images`); otherwise a content hash of the files."""
    path = Path(path)
    for folder in (path, path.parent):
        rec = load_record(folder) if folder.is_dir() else None
        if rec is not None:
            return rec.key
    return content_key(path)


def content_key(path: Path) -> str:
    """sha256 over relative names and bytes of every file under `path` (or of the file)."""
    path = Path(path)
    if not path.exists():
        raise StageError("cache", "missing_input", f"{path} does not exist")
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for p in files:
        h.update(p.relative_to(path.parent if p == path else path).as_posix().encode() + b"\0")
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:16]


def load_record(out_dir: Path) -> Optional[StageRecord]:
    path = Path(out_dir) / MARKER
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        return StageRecord(**data)
    except (ValueError, TypeError):
        return None


def finished_key(out_dir: Path, stage: str, detail: str) -> str:
    """Key of the finished stage output `out_dir` that `stage` reads; StageError `missing_input`
    (with `detail`) when the folder holds no marker."""
    rec = load_record(out_dir)
    if rec is None:
        raise StageError(stage, "missing_input", detail)
    return rec.key


def is_done(out_dir: Path, key: str) -> bool:
    rec = load_record(out_dir)
    return rec is not None and rec.key == key


def mark_done(out_dir: Path, stage: str, key: str, summary: dict, seconds: float) -> StageRecord:
    """Atomically write the marker (write to a temp file, then rename)."""
    out_dir = Path(out_dir)
    rec = StageRecord(stage=stage, key=key, summary=to_jsonable(summary), seconds=seconds,
                      code_version=code_version())
    fd, tmp = tempfile.mkstemp(dir=out_dir, prefix=".stage-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(to_jsonable(rec), f, indent=2)
    os.chmod(tmp, 0o644)  # mkstemp creates 0600
    os.replace(tmp, out_dir / MARKER)
    return rec


def fresh_dir(out_dir: Path) -> Path:
    """Empty `out_dir` (a stale, unfinished output) and return it."""
    out_dir = Path(out_dir)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    return out_dir


class Timer:
    def __enter__(self) -> "Timer":
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc: object) -> None:
        self.seconds = time.perf_counter() - self.t0
