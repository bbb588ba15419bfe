"""Shared fixtures: the real-data folder (../shared/data) and temp dirs."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parent.parent
SHARED_DATA = Path(os.environ.get("VID2SIM_SHARED_DATA", PROJECT_ROOT.parent / "shared" / "data"))


def shared_data_path(name: str) -> Path:
    """Path to a real-data folder, or skip the test with a clear message when absent."""
    path = SHARED_DATA / name
    if not path.exists():
        pytest.skip(f"real data {path} is absent (tests read ../shared/data beside the project)")
    return path


@pytest.fixture
def shared_data():
    return shared_data_path
