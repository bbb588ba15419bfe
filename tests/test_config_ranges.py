"""Every numeric field of every config the command line runs with (`vid2sim config show`'s
sections, walked from the configs themselves) refuses a value outside its range by name, and its
default lies inside."""

from __future__ import annotations

import json
import math
import re
from typing import Any

import pytest
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.cli.ranges import RangeError, field_range
from vid2sim.cli.settings import (SECTIONS, _placeholder, apply_eval_overrides, apply_overrides, describe_section,
                                  section_config)


def base(section: str) -> Any:
    conf = section_config(section)
    return _placeholder(conf) if isinstance(conf, type) else conf


NUMERIC_TYPE = re.compile(r"\b(int|float)\b")


def fields(section: str) -> list[tuple[str, Any, bool]]:
    """(path, default, holds floats) of every numeric field, unset (None) sections followed into, as
    `config show` lists them."""
    return [(r.path, r.default, "float" in r.type) for r in describe_section(section)
            if not r.section and NUMERIC_TYPE.search(r.type) and "bool" not in r.type]


FIELDS = [(s, *row) for s in SECTIONS for row in fields(s)]


def apply(section: str, sets: list[str]) -> Any:
    return (apply_eval_overrides if section == "eval" else apply_overrides)(base(section), sets)


def bad_values(path: str, floats: bool) -> list[Any]:
    rng = field_range(path.rsplit(".", 1)[-1])
    out: list[Any] = []
    if rng.lo is not None:
        out.append(rng.lo if rng.lo_open else (rng.lo - 1 if not floats else rng.lo - 0.5))
    if rng.hi is not None:
        out.append(rng.hi + 1)
    if floats:
        out += [math.nan, math.inf]
    return out


def as_set(path: str, value: Any, bad: Any) -> str:
    """`path=...` with `bad` as the value (the first item for a tuple / list field)."""
    if isinstance(value, (list, tuple)):
        return f"{path}={json.dumps([bad, *list(value)[1:]] if value else [bad])}"
    return f"{path}={bad}"


def test_the_walk_covers_every_section():
    paths = {(s, p) for s, p, _, _ in FIELDS}
    assert {("ingest", "metric.capture_height_m"), ("train", "total_steps"), ("train", "sac.batch_size"),
            ("eval", "trials"), ("env", "augment.fog_prob"), ("eval", "env.camera.width")} <= paths
    assert len(FIELDS) > 250


@pytest.mark.parametrize("section", SECTIONS)
def test_defaults_lie_inside_their_ranges(section):
    apply(section, [])


@pytest.mark.parametrize("section,path,value,floats", FIELDS, ids=[f"{s}:{p}" for s, p, _, _ in FIELDS])
def test_out_of_range_value_is_named(section, path, value, floats):
    values = bad_values(path, floats)
    assert values, f"{path} has no range"
    for bad in values:
        with pytest.raises(RangeError, match=rf"{re.escape(path)}: .* is out of range \(must be "):
            apply(section, [as_set(path, value, bad)])


@pytest.mark.parametrize("sets,named", [
    (["metric.capture_height_m=0"], "metric.capture_height_m"),
    (["decode.fps=-1"], "decode.fps"),
    (["decode.jpeg_quality=101"], "decode.jpeg_quality"),
])
def test_cli_reports_a_field_out_of_range(sets, named):
    args = ["config", "show", "ingest", *[a for s in sets for a in ("--set", s)], "--json"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 2 and r.stderr.startswith(f"error: --set {sets[0]}: {named}: ")
    assert json.loads(r.stdout)["error"]["type"] == "RangeError"
