"""The user errors a hostile probe met as raw tracebacks, NaN metrics or silent defaults: each is
now a named one-line error (exit 2), and with `--json` a JSON error object on stdout."""

from __future__ import annotations

import json

import pytest
from registry_fixtures import make_bundle
from typer.testing import CliRunner

from vid2sim.cli.app import app
from vid2sim.cli.errors import ErrorReport, one_line, report_of, wants_json
from vid2sim.registry import Registry


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> str:
    tmp = tmp_path_factory.mktemp("reg")
    reg = Registry(tmp / "reg")
    reg.add(make_bundle(tmp / "b0", "s0"))
    return str(reg.root)


def _error(args: list[str]) -> tuple[str, dict | None]:
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 2, r.output[-2000:]
    assert "Traceback" not in r.output
    lines = r.stderr.strip().splitlines()
    assert lines and lines[-1].startswith("error: "), r.stderr
    return lines[-1], (json.loads(r.stdout) if "--json" in args else None)


CASES = {
    "train --steps -5": (["train", "--registry", "R", "--run", "RUN", "--steps", "-5"], "--steps"),
    "train --envs 0": (["train", "--registry", "R", "--run", "RUN", "--envs", "0"], "--envs"),
    "train --batch-size 0": (["train", "--registry", "R", "--run", "RUN", "--batch-size", "0"], "--batch-size"),
    "train --frames 9": (["train", "--registry", "R", "--run", "RUN", "--frames", "9"], "--frames"),
    "train on no registry": (["train", "--registry", "NOWHERE", "--run", "RUN", "--actors", "0"], "no registry"),
    "train --set sac.gamma=2": (["train", "--registry", "R", "--run", "RUN", "--set", "sac.gamma=2"], "sac.gamma"),
    "eval policy --trials 0": (["eval", "policy", "--policy", "random", "--registry", "R", "--trials", "0"],
                               "--trials"),
    "eval policy --max-steps -1": (["eval", "policy", "--policy", "random", "--registry", "R", "--max-steps", "-1"],
                                   "--max-steps"),
    "eval policy --set env.reward.max_steps=0": (["eval", "policy", "--policy", "random", "--registry", "R", "--set",
                                                  "env.reward.max_steps=0"], "env.reward.max_steps"),
    "study --trials 0": (["study", "--registry", "R", "--out", "OUT", "--trials", "0"], "--trials"),
    "study --counts x": (["study", "--registry", "R", "--out", "OUT", "--counts", "1,x", "--json"], "--counts"),
    "ingest --capture-height 0": (["ingest", "MISSING", "--capture-height", "0"], "--capture-height"),
    "ingest --set metric.capture_height_m=0": (["ingest", "MISSING", "--set", "metric.capture_height_m=0"],
                                               "metric.capture_height_m"),
    "ingest a missing file": (["ingest", "MISSING", "--json"], "MISSING"),
    "registry gc --grace-seconds nan": (["registry", "gc", "-r", "R", "--grace-seconds", "nan"], "--grace-seconds"),
    "registry query --memory 1KB": (["registry", "query", "select 1", "-r", "R", "--memory", "1KB", "--json"],
                                    "memory limit"),
    "registry compact on a bad path": (["registry", "compact", "-r", "NOWHERE", "--json"], "no registry"),
    "registry checkout --dest below a file": (["registry", "checkout", "s0", "-r", "R", "--dest", "FILE/co"],
                                              "--dest"),
    "registry list on memory://": (["registry", "list", "-r", "memory://vid2sim", "--json"], "memory://"),
    "registry split --test-fraction 1.5": (["registry", "split", "-r", "R", "--test-fraction", "1.5"],
                                           "--test-fraction"),
    "sfm metric --height 0": (["sfm", "metric", "--sfm", "MISSING", "--out", "OUT", "--height", "0"], "--height"),
    "sfm run --camera-params x": (["sfm", "run", "--images", "R", "--out", "OUT", "--camera-params", "1,x"],
                                  "--camera-params"),
}


@pytest.mark.parametrize("name", list(CASES))
def test_named_one_line_error(name, root, tmp_path):
    args, named = CASES[name]
    blocker = tmp_path / "file"
    blocker.write_text("x")
    subst = {"R": root, "RUN": str(tmp_path / "run"), "OUT": str(tmp_path / "out"), "NOWHERE": str(tmp_path / "no"),
             "MISSING": str(tmp_path / "missing.mp4")}
    argv = [subst.get(a, a).replace("FILE", str(blocker)) for a in args]
    line, obj = _error(argv)
    assert subst.get(named, named) in line, line
    if obj is not None:
        assert obj["exit_code"] == 2 and obj["error"]["message"] in line
    assert not (tmp_path / "run").exists() and not (tmp_path / "out").exists() and not (tmp_path / "no").exists()


def test_report_names_input_and_reason():
    rep = report_of(FileNotFoundError(2, "No such file or directory", "/data/x.mp4"))
    assert rep == ErrorReport("FileNotFoundError", "/data/x.mp4", "No such file or directory")
    assert rep.to_json()["error"]["message"] == "/data/x.mp4: No such file or directory"
    assert one_line("a\n  b\tc") == "a b c"
    assert wants_json(["registry", "list", "--json"]) and not wants_json(["ingest", "--", "--json"])

