"""Checks a command runs on its inputs before any slow work (Ray, decoding, training) starts."""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Optional

from vid2sim.cli.errors import InputError


def is_uri(text: str) -> bool:
    return "://" in text


def existing_sources(inputs: Iterable[str], flag: str = "INPUTS") -> list[str]:
    """Local inputs must exist (URIs are checked when fetched)."""
    items = list(inputs)
    for item in items:
        if not is_uri(item) and not Path(item).exists():
            raise InputError(item, f"{flag}: no such file or folder")
    return items


def creatable_folder(path: Optional[str], flag: str) -> Optional[str]:
    """A folder that exists or can be made: no existing part of the path is a file."""
    if path is None or is_uri(path):
        return path
    p = Path(path).expanduser().absolute()
    for part in [p, *p.parents]:
        if part.exists():
            if not part.is_dir():
                raise InputError(path, f"{flag}: {part} is a file, not a folder")
            break
    return path


def registry_root(root: Optional[str]) -> str:
    """A root that holds a registry (RegistryNotFound names it otherwise); the default when None."""
    from vid2sim.registry.store import Registry, default_root

    root = root or default_root()
    Registry(root).require()
    return root
