"""`vid2sim registry ...` end to end (typer CliRunner in-process, and the installed entry point)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from registry_fixtures import make_bundle
from typer.testing import CliRunner

from vid2sim.cli.app import app

runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, ["registry", *args])


def test_cli_flow(tmp_path):
    root = str(tmp_path / "reg")
    b = make_bundle(tmp_path / "a", "a", group="v1")
    r = run("add", str(b), "--registry", root, "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["version"] == 1 and json.loads(r.stdout)["noop"] is False
    assert json.loads(run("add", str(b), "-r", root, "--json").stdout)["noop"] is True
    run("add", str(make_bundle(tmp_path / "b", "b", group="v2", seed=1)), "-r", root)
    assert run("tag", "a", "good", "-r", root).exit_code == 0
    listed = json.loads(run("list", "-r", root, "--json").stdout)
    assert [(x["scene_id"], x["version"], x["tags"]) for x in listed] == [("a", 2, ["good"]), ("b", 1, [])]
    old = json.loads(run("list", "-r", root, "--json", "--as-of", "1").stdout)
    assert [x["scene_id"] for x in old] == ["a"]
    shown = json.loads(run("show", "a@1", "-r", root, "--json").stdout)
    assert shown["tags"] == [] and {a["name"] for a in shown["artifacts"]} >= {"splats.ply", "scene.json"}
    hist = json.loads(run("history", "a", "-r", root, "--json").stdout)
    assert [h["event"] for h in hist] == ["add", "tag"]
    assert run("untag", "a", "good", "-r", root, "--json").exit_code == 0
    dep = json.loads(run("deprecate", "b", "--reason", "blurry", "-r", root, "--json").stdout)
    assert dep["status"] == "deprecated"
    q = json.loads(run("query", "select scene_id, status from latest order by 1", "-r", root, "--json").stdout)
    assert q == [{"scene_id": "a", "status": "active"}, {"scene_id": "b", "status": "deprecated"}]
    sp = json.loads(run("split", "--seed", "1", "--test-fraction", "0", "--train-size", "1", "-r", root,
                        "--json").stdout)
    assert sp["train"] == ["a"] and sp["train_subsets"] == {"1": ["a"]}
    co = json.loads(run("checkout", "a", "--dest", str(tmp_path / "co"), "-r", root, "--json").stdout)
    assert (Path(co["path"]) / "splats.ply").is_file()
    assert json.loads(run("verify", "-r", root, "--json").stdout) == {"ok": True, "problems": []}
    assert json.loads(run("gc", "-r", root, "--json", "--grace-seconds", "0").stdout)["removed"] == []
    before = run("history", "-r", root, "--json").stdout
    assert run("compact", "-r", root, "--json").exit_code == 0
    assert run("history", "-r", root, "--json").stdout == before  # compaction changes no row
    vac = json.loads(run("compact", "-r", root, "--json", "--vacuum-hours", "0", "--dry-run").stdout)
    assert vac["numFilesRemoved"] == 0 and len(vac["vacuumed"]) >= 2  # files the first compact replaced
    assert run("list", "-r", root, "--as-of", "1", "--json").exit_code == 0  # dry run: still readable
    for table_cmd in (["list"], ["show", "a"], ["history"], ["query", "select 1 as x"], ["split"], ["verify"]):
        assert run(*table_cmd, "-r", root).exit_code == 0  # rich tables render


def test_cli_verify_fails_on_corrupt_blob(tmp_path):
    root = tmp_path / "reg"
    r = run("add", str(make_bundle(tmp_path / "a", "a")), "-r", str(root), "--json")
    sha = next(a["sha256"] for a in json.loads(r.stdout)["artifacts"] if a["name"] == "walkable.npz")
    blob = root / "blobs" / sha[:2] / sha[2:]
    blob.write_bytes(b"not the grid")
    r = run("verify", "-r", str(root))
    assert r.exit_code == 1
    assert sha in r.stderr and "a@1:walkable.npz" in r.stderr and "corrupt" in r.stderr


def test_cli_bad_input_named_error_no_traceback(tmp_path):
    root = tmp_path / "reg"
    b = make_bundle(tmp_path / "a", "a")
    (b / "scene.json").unlink()
    r = run("add", str(b), "-r", str(root))
    assert r.exit_code == 2 and "scene.json" in r.stderr and "missing scene.json" in r.stderr
    assert "Traceback" not in r.output and not root.exists()
    for args in (["show", "nope"], ["show", "a@x"], ["query", "selec"], ["list", "--as-of", "yesterday"]):
        r = run(*args, "-r", str(root))
        assert r.exit_code == 2 and r.stderr.startswith("error:"), (args, r.output)


def test_installed_entry_point_json(tmp_path):
    exe = Path(sys.executable).with_name("vid2sim")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "vid2sim.cli"]
    env = {**os.environ, "VID2SIM_REGISTRY": str(tmp_path / "reg")}
    b = make_bundle(tmp_path / "a", "a")
    subprocess.run([*cmd, "registry", "add", str(b)], check=True, env=env, capture_output=True)
    out = subprocess.run([*cmd, "registry", "list", "--json"], check=True, env=env, capture_output=True, text=True)
    assert [x["scene_id"] for x in json.loads(out.stdout)] == ["a"]
    bad = subprocess.run([*cmd, "registry", "show", "zzz"], env=env, capture_output=True, text=True)
    assert bad.returncode == 2 and "zzz" in bad.stderr and "Traceback" not in bad.stderr
