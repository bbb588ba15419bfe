"""benchmarks/distill.py reuses (or resumes) a run folder only for the scenes it trained on."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

import distill as distill_bench  # noqa: E402  (benchmarks/distill.py)


def test_a_run_folder_trained_on_other_scenes_is_refused(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps({"scene_ids": ["street-v1", "street-v2"]}))
    distill_bench.check_same_scenes(tmp_path, ["street-v2", "street-v1"])  # the same scenes: reused
    distill_bench.check_same_scenes(tmp_path, None)  # the split's training side: not checked
    distill_bench.check_same_scenes(tmp_path / "new", ["street-v3"])  # no run there yet
    refused = r"trained on 2 scenes \(street-v1, street-v2, \.\.\.\), the call asks for a different set of 3"
    with pytest.raises(SystemExit, match=refused):
        distill_bench.check_same_scenes(tmp_path, ["street-v1", "street-v2", "street-v3"])
