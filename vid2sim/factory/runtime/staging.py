"""Stage folders between a work store and a node's scratch copy of the clip folder.

With a work store (an object-store URI), a step runs in node-local scratch
(`$VID2SIM_SCRATCH`, default the system temp dir): the finished folders it may read (marker
present in the store) that the node does not already hold with the same marker are fetched
into `<scratch>/<clip>/<folder>/`, and afterwards its own folder is uploaded, marker last,
unless the store already holds that marker. Nothing assumes that two tasks share a disk; the
marker in the store is the only "done" signal. `runner.py` is the one caller.

Every transfer adds its wall seconds, bytes and folders to this process's running totals
(`transfer_totals()`): the seconds include the marker look-ups that decide what to move.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from vid2sim.factory.ingest.sources import is_uri, resolve_source
from vid2sim.factory.runtime.object_store import MARKER, ObjectStore

if TYPE_CHECKING:
    from vid2sim.factory.runtime.config import ClipJob


_TOTALS = {"down_s": 0.0, "down_bytes": 0, "down_folders": 0, "up_s": 0.0, "up_bytes": 0, "up_folders": 0,
           "source_s": 0.0, "source_bytes": 0}


def transfer_totals() -> dict:
    """This process's running transfer totals (a copy): wall seconds, bytes and folders moved
    down (store -> scratch: `sync_down`, `fetch_from_store`), up (`sync_up`) and a URI source
    fetched by `localize_source`. Subtract two readings for the transfers of one span."""
    return dict(_TOTALS)


@contextmanager
def _timed(kind: str):
    t0 = time.perf_counter()
    try:
        yield
    finally:
        _TOTALS[f"{kind}_s"] += time.perf_counter() - t0


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def scratch_root() -> Path:
    """This node's scratch folder (`$VID2SIM_SCRATCH`, else `<tmp>/vid2sim-scratch`)."""
    return Path(os.environ.get("VID2SIM_SCRATCH") or Path(tempfile.gettempdir()) / "vid2sim-scratch")


def local_clip_dir(work_uri: str, clip_id: str) -> Path:
    """Node-local copy of a clip's folder, keyed by the work store so runs never mix."""
    tag = hashlib.sha256(work_uri.encode()).hexdigest()[:12]
    return scratch_root() / f"work-{tag}" / clip_id


def sync_down(store: ObjectStore, clip_id: str, local: Path, names: tuple[str, ...]) -> list[str]:
    """Fetch the clip's finished folders `names` the node lacks (or holds stale); returns them."""
    fetched = []
    with _timed("down"):
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
            _TOTALS["down_bytes"] += _size(local / name)
            _TOTALS["down_folders"] += 1
    return fetched


def sync_up(store: ObjectStore, clip_id: str, local: Path, folders: list[str]) -> list[str]:
    """Upload finished folders the store lacks (marker last); returns them."""
    pushed = []
    with _timed("up"):
        for rel in dict.fromkeys(f.split("/")[0] for f in folders):  # the stage folder holds the marker
            marker = local / rel / MARKER
            if not marker.is_file() or store.marker(f"{clip_id}/{rel}") == marker.read_bytes():
                continue
            store.put_dir(local / rel, f"{clip_id}/{rel}")
            pushed.append(rel)
            _TOTALS["up_bytes"] += _size(local / rel)
            _TOTALS["up_folders"] += 1
    return pushed


def localize_source(job: "ClipJob") -> "ClipJob":
    """The job with a URI source re-resolved on this node when the driver's cached copy is not here."""
    source = job.spec.source
    if Path(source.path).exists() or not is_uri(source.uri):
        return job
    with _timed("source"):
        fresh = resolve_source(source.uri, scratch_root() / "cache", source.sha256)
    if Path(fresh.path).is_file():
        _TOTALS["source_bytes"] += Path(fresh.path).stat().st_size
    return replace(job, spec=replace(job.spec, source=fresh))


def fetch_from_store(work_uri: str, clip_id: str, rel: str) -> Path:
    """Local copy (this node's scratch) of `<clip>/<rel>` from the store, e.g. a bundle to commit."""
    local = local_clip_dir(work_uri, clip_id)
    sync_down(ObjectStore(work_uri), clip_id, local, (rel.split("/")[0],))
    return local / rel
