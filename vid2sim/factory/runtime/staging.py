"""Run a clip's stage on any node: inputs come from the work store, outputs go back to it.

With `ctx["work_uri"]` set (an object-store URI or a folder not shared between nodes), a stage
runs in node-local scratch (`$VID2SIM_SCRATCH`, default the system temp dir):
1. every finished stage folder of the clip (marker present in the store) that the node does not
   already hold with the same marker is downloaded to `<scratch>/<clip>/<stage>/`;
2. context values ending in `_dir` are stored relative to the clip folder and resolved against
   the local copy;
3. the stage runs (its own `stage.json` cache check sees finished inputs and outputs);
4. the stage folder of each path it returns is uploaded, marker last, unless the store already
   holds that marker.
Nothing assumes that two tasks share a disk; the marker in the store is the only "done" signal.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Callable

from vid2sim.factory.ingest.sources import is_uri, resolve_source
from vid2sim.factory.runtime.object_store import MARKER, ObjectStore

STAGE_FOLDERS = ("posed", "decode", "masks", "sfm", "metric", "recon", "meshing", "walkable", "bundle")


def scratch_root() -> Path:
    """This node's scratch folder (`$VID2SIM_SCRATCH`, else `<tmp>/vid2sim-scratch`)."""
    return Path(os.environ.get("VID2SIM_SCRATCH") or Path(tempfile.gettempdir()) / "vid2sim-scratch")


def local_clip_dir(work_uri: str, clip_id: str) -> Path:
    """Node-local copy of a clip's folder, keyed by the work store so runs never mix."""
    tag = hashlib.sha256(work_uri.encode()).hexdigest()[:12]
    return scratch_root() / f"work-{tag}" / clip_id


def sync_down(store: ObjectStore, clip_id: str, local: Path,
              names: tuple[str, ...] = STAGE_FOLDERS) -> list[str]:
    """Fetch the clip's finished stage folders the node lacks (or holds stale); returns them."""
    fetched = []
    for name in names:
        remote = store.marker(f"{clip_id}/{name}")
        if remote is None:
            continue
        mine = local / name / MARKER
        if mine.is_file() and mine.read_bytes() == remote:
            continue
        shutil.rmtree(local / name, ignore_errors=True)
        store.get_dir(f"{clip_id}/{name}", local / name)
        fetched.append(name)
    return fetched


def sync_up(store: ObjectStore, clip_id: str, local: Path, folders: list[str]) -> list[str]:
    """Upload finished folders the store lacks (marker last); returns them."""
    pushed = []
    for rel in dict.fromkeys(f.split("/")[0] for f in folders):  # the stage folder holds the marker
        marker = local / rel / MARKER
        if not marker.is_file() or store.marker(f"{clip_id}/{rel}") == marker.read_bytes():
            continue
        store.put_dir(local / rel, f"{clip_id}/{rel}")
        pushed.append(rel)
    return pushed


def _localize_source(ctx: dict) -> dict:
    """Re-resolve a URI source on this node when the driver's cached copy is not here."""
    job = ctx.get("job")
    source = getattr(getattr(job, "spec", None), "source", None)
    if source is None or Path(source.path).exists() or not is_uri(source.uri):
        return ctx
    fresh = resolve_source(source.uri, scratch_root() / "cache", source.sha256)
    return {**ctx, "job": replace(job, spec=replace(job.spec, source=fresh))}


def fetch_from_store(work_uri: str, clip_id: str, rel: str) -> Path:
    """Local copy (this node's scratch) of `<clip>/<rel>` from the store, e.g. a bundle to commit."""
    local = local_clip_dir(work_uri, clip_id)
    sync_down(ObjectStore(work_uri), clip_id, local, (rel.split("/")[0],))
    return local / rel


def run_on_store(fn: Callable[[dict], dict], ctx: dict) -> dict:
    """Run stage `fn` against the work store (see module doc); returns relative `_dir` keys."""
    store, clip_id = ObjectStore(ctx["work_uri"]), ctx["clip_id"]
    local = local_clip_dir(ctx["work_uri"], clip_id)
    local.mkdir(parents=True, exist_ok=True)
    sync_down(store, clip_id, local)
    local_ctx = {k: str(local / v) if k.endswith("_dir") and isinstance(v, str) and not os.path.isabs(v)
                 else v for k, v in ctx.items()}
    local_ctx["clip_dir"] = str(local)
    added = fn(_localize_source(local_ctx)) or {}
    rel = {k: os.path.relpath(v, local) if k.endswith("_dir") else v for k, v in added.items()}
    sync_up(store, clip_id, local, [v for k, v in rel.items() if k.endswith("_dir")])
    return rel


class OnStore:
    """Picklable stage wrapper: `OnStore(fn)(ctx)` runs `fn` via `run_on_store` when the
    context names a work store, and plainly otherwise."""

    def __init__(self, fn: Callable[[dict], dict]) -> None:
        self.fn = fn
        self.__name__ = getattr(fn, "__name__", "stage")

    def __call__(self, ctx: dict) -> dict:
        if ctx.get("work_uri"):
            return run_on_store(self.fn, ctx)
        return self.fn(ctx)
