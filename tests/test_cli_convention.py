"""Every `vid2sim` command, discovered from the parser, answers bad input by one convention:
exit 2, one line `error: INPUT: REASON` on stderr naming the input, no traceback, and with
`--json` a JSON error object on stdout. Every numeric option declares its range.

All calls run in-process (typer's CliRunner); the bad inputs fail before any slow work starts.
"""

from __future__ import annotations

import json
import math
from typing import Any, Iterator

import pytest
import typer
from typer.testing import CliRunner

from vid2sim.cli.app import app

ROOT = typer.main.get_command(app)


def leaves(cmd: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    """The argv prefix of every runnable command under `cmd`."""
    subs = getattr(cmd, "commands", None) or {}
    if not subs:
        yield path
    for name, sub in sorted(subs.items()):
        yield from leaves(sub, path + (name,))


COMMANDS = list(leaves(ROOT))
IDS = [" ".join(c) for c in COMMANDS]


def command(path: tuple[str, ...]) -> Any:
    cmd = ROOT
    for name in path:
        cmd = cmd.commands[name]
    return cmd


def has_json(path: tuple[str, ...]) -> bool:
    return any("--json" in getattr(p, "opts", []) for p in command(path).params)


def numeric(param: Any) -> type | None:
    """int / float when the option takes numbers (lists of them too), else None."""
    ann = param.type_descriptor.annotation
    for kind in (int, float):
        if ann is kind or kind in getattr(ann, "__args__", ()):
            return kind
    return None


NUMERIC = [(path, p) for path in COMMANDS for p in command(path).params
           if p.param_type_name == "option" and numeric(p) and not getattr(p, "is_flag", False)]


def check(result: Any, names: str, as_json: bool) -> dict | None:
    """The convention, for a result whose error line must contain `names`."""
    assert "Traceback" not in result.output, result.output[-2000:]
    assert result.exit_code == 2, (result.exit_code, result.output[-2000:])
    errors = [ln for ln in result.stderr.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and result.stderr.rstrip().endswith(errors[0]), result.stderr
    assert names in errors[0], (names, errors[0])
    if not as_json:
        return None
    obj = json.loads(result.stdout)
    assert obj["exit_code"] == 2 and obj["error"]["message"] in errors[0] and obj["error"]["type"]
    return obj


def run(args: list[str]) -> Any:
    return CliRunner().invoke(app, args)


def test_the_walk_finds_every_command():
    assert {"registry add", "registry query", "train", "study", "eval policy", "ingest", "config show"} <= set(IDS)
    assert len(IDS) >= 25


@pytest.mark.parametrize("path", COMMANDS, ids=IDS)
def test_unknown_option(path):
    as_json = has_json(path)
    r = run([*path, *(["--json"] if as_json else []), "--no-such-option"])
    obj = check(r, "--no-such-option", as_json)
    assert obj is None or obj["error"]["input"] == "--no-such-option"


@pytest.mark.parametrize("path", COMMANDS, ids=IDS)
def test_missing_and_unusable_paths(path, tmp_path):
    """Every argument, required option and --registry names a path below a regular file: nothing
    can be read or created there."""
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    args: list[str] = []
    for p in command(path).params:
        bad = str(blocker / p.name)
        if p.param_type_name == "argument":
            args.append(bad)
        elif p.required or "--registry" in p.opts:
            args += [p.opts[0], bad]
    if not args:
        pytest.skip("takes no input")
    as_json = has_json(path)
    check(run([*path, *args, *(["--json"] if as_json else [])]), str(blocker), as_json)


def out_of_range(kind: type, lo: float | None, hi: float | None) -> list[str]:
    values = [] if lo is None else [str(lo - 1)]
    values += [] if hi is None else [str(hi * 2 + 1)]
    return values + (["nan", "inf"] if kind is float else ["1.5"])


@pytest.mark.parametrize("path,param", NUMERIC, ids=[f"{' '.join(c)} {p.opts[0]}" for c, p in NUMERIC])
def test_numeric_option_ranges(path, param):
    kind = numeric(param)
    assert param.min is not None, f"{param.opts[0]} declares no range"
    if kind is float:
        assert param.max is not None and math.isfinite(param.max), f"{param.opts[0]} declares no upper bound"
    as_json = has_json(path)
    for value in out_of_range(kind, param.min, param.max):
        obj = check(run([*path, param.opts[0], value, *(["--json"] if as_json else [])]), param.opts[0], as_json)
        assert obj is None or obj["error"]["input"] == param.opts[0]
