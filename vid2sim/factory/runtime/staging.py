"""Stage folders between a work store and a node's scratch copy of the clip folder.

With a work store (an object-store URI), a step runs in node-local scratch
(`$VID2SIM_SCRATCH`, default the system temp dir): the finished folders it may read (marker
present in the store) that the node does not already hold with the same marker are fetched
into `<scratch>/<clip>/<folder>/`, and afterwards its own folder is uploaded, marker last,
unless the store already holds that marker. Nothing assumes that two tasks share a disk; the
marker in the store is the only "done" signal. `runner.py` is the one caller.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from vid2sim.factory.ingest.sources import is_uri, resolve_source
from vid2sim.factory.runtime.object_store import MARKER, ObjectStore

if TYPE_CHECKING:
    from vid2sim.factory.runtime.config import ClipJob


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


def localize_source(job: "ClipJob") -> "ClipJob":
    """The job with a URI source re-resolved on this node when the driver's cached copy is not here."""
    source = job.spec.source
    if Path(source.path).exists() or not is_uri(source.uri):
        return job
    fresh = resolve_source(source.uri, scratch_root() / "cache", source.sha256)
    return replace(job, spec=replace(job.spec, source=fresh))


def fetch_from_store(work_uri: str, clip_id: str, rel: str) -> Path:
    """Local copy (this node's scratch) of `<clip>/<rel>` from the store, e.g. a bundle to commit."""
    local = local_clip_dir(work_uri, clip_id)
    sync_down(ObjectStore(work_uri), clip_id, local, (rel.split("/")[0],))
    return local / rel
