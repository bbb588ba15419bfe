"""Where a scene comes from: a bundle folder, or a scene id checked out of a registry.

Reads the registry's manifest and writes a hash-verified checkout under $VID2SIM_CHECKOUTS
(default ./vid2sim-checkouts), the same place the envs use.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

from vid2sim.registry import Registry
from vid2sim.registry.errors import RegistryError, RegistryNotFound, SceneNotFound
from vid2sim.registry.store import default_root, parse_ref
from vid2sim.viewer.errors import UnknownScene, ViewerError


def checkout_root() -> Path:
    return Path(os.environ.get("VID2SIM_CHECKOUTS", "vid2sim-checkouts"))


def open_registry(root: Optional[str]) -> Registry:
    """The registry at `root` (default $VID2SIM_REGISTRY or ./vid2sim-registry)."""
    root = root or default_root()
    try:
        reg = Registry(root)
        reg.list()
    except RegistryNotFound:
        raise UnknownScene(f"{root}: no registry there (pass --registry ROOT)") from None
    except RegistryError as e:
        raise UnknownScene(f"{root}: {e}") from None
    return reg


def resolve_bundle(target: str, registry: Optional[str] = None, checkouts: Optional[Path] = None) -> Path:
    """A bundle folder for `target` (an existing folder, or SCENE[@V] of the registry, checked out
    under `checkouts` (default `checkout_root()`) in a folder named by its ref and content hash)."""
    if Path(target).is_dir():
        return Path(target)
    try:
        scene_id, version = parse_ref(target)
    except RegistryError as e:
        raise UnknownScene(str(e)) from None
    reg = open_registry(registry)
    try:
        rec = reg.show(scene_id, version)
    except (SceneNotFound, KeyError):
        known = ", ".join(r.scene_id for r in reg.list()[:8]) or "none"
        raise UnknownScene(f"unknown scene {target!r}: not a folder and not in the registry at {reg.root} "
                           f"(scenes there: {known})") from None
    dest = Path(checkouts or checkout_root()) / f"{rec.ref}-{rec.content_hash[:12]}"
    try:
        return reg.checkout(rec.scene_id, rec.version, dest=dest)
    except RegistryError as e:  # a damaged blob, an unwritable destination: named, not a traceback
        raise ViewerError(f"{rec.ref}: cannot check the scene out ({e})") from None
