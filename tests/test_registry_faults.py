"""Registry faults on real files: lost or damaged manifest logs, unaccounted and corrupt blobs.

Each test damages a real registry the way a user or a crash would (deleting or truncating real
Delta log files, corrupting real blobs) and checks that the registry says so instead of looking
healthy, and that `gc` never deletes blobs of scenes whose history it cannot see.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from registry_fixtures import make_bundle

from vid2sim.registry import Registry
from vid2sim.registry.errors import HistoryLost, RegistryNotFound

LOG = Path("manifests") / "_delta_log"


def _registry(tmp_path: Path, n: int = 4) -> Registry:
    reg = Registry(tmp_path / "reg")
    for i in range(n):
        reg.add(make_bundle(tmp_path / f"b{i}", f"s{i}", seed=i))
    return reg


def _stored(reg: Registry) -> set[str]:
    return {b.sha256 for b in reg.blobs.list() if not b.is_temp}


def _cli(*args: str):
    """`vid2sim registry ARGS` in-process (result has returncode, stdout, stderr)."""
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    r = CliRunner().invoke(app, ["registry", *args])
    r.returncode = r.exit_code
    return r


def _proc(*args: str) -> subprocess.CompletedProcess:
    """`vid2sim registry ARGS` in a real process (to see aborts and exit codes as a shell would)."""
    return subprocess.run([sys.executable, "-m", "vid2sim.cli", "registry", *args], capture_output=True,
                          text=True, timeout=120)


@pytest.mark.parametrize("gone", ["manifests/_delta_log", "manifests"])
def test_deleted_log_is_lost_history_and_gc_refuses(tmp_path, gone):
    reg = _registry(tmp_path)
    blobs = _stored(reg)
    shutil.rmtree(Path(reg.root) / gone)
    fresh = Registry(reg.root)
    with pytest.raises(HistoryLost, match="manifest log is missing"):
        fresh.list()
    problems = fresh.verify()
    assert problems and "lost its history" in problems[0]
    with pytest.raises(HistoryLost):
        fresh.gc(grace_s=0)
    with pytest.raises(HistoryLost):  # nothing is committed on top of lost history
        fresh.add(tmp_path / "b0")
    assert _stored(fresh) == blobs and not (Path(reg.root) / LOG).exists()
    assert sorted(fresh.gc(grace_s=0, force=True)) == sorted(blobs)  # explicit force does it
    assert _stored(fresh) == set()


def _log_file(reg: Registry, v: int) -> Path:
    return Path(reg.root) / LOG / f"{v:020d}.json"


def test_truncated_middle_log_file_is_reported_not_hidden(tmp_path):
    reg = _registry(tmp_path)  # versions: 0 create, 1..4 one add each
    blobs = _stored(reg)
    _log_file(reg, 2).write_bytes(b"")  # the commit that added s1
    fresh = Registry(reg.root)
    for read in (fresh.list, fresh.history, lambda: fresh.show("s0")):
        with pytest.raises(HistoryLost, match="version 2 is empty"):
            read()
    problems = fresh.verify()
    assert any("version 2 is empty" in p for p in problems)
    assert any("referenced by no manifest row" in p for p in problems)  # s1's own blobs
    with pytest.raises(HistoryLost, match="gc refused"):
        fresh.gc(grace_s=0)
    with pytest.raises(HistoryLost, match="version 2 is empty"):
        fresh.add(make_bundle(tmp_path / "b9", "s9", seed=9))
    assert _stored(fresh) == blobs and len(list((Path(reg.root) / LOG).glob("*.json"))) == 5


@pytest.mark.parametrize("damage", ["delete", "garbage"])
def test_missing_or_garbled_log_file_is_one_named_line(tmp_path, damage):
    reg = _registry(tmp_path)
    f = _log_file(reg, 2)
    f.unlink() if damage == "delete" else f.write_text("{not json\n")
    r = _cli("list", "-r", reg.root)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "manifest log" in r.stderr and "Traceback" not in r.stderr
    v = _cli("verify", "-r", reg.root)
    assert v.returncode == 1 and "version 2" in v.stderr
    assert _cli("gc", "-r", reg.root, "--grace-seconds", "0").returncode == 2


def test_deleted_manifest_data_file_is_named_error_not_abort(tmp_path):
    reg = _registry(tmp_path)
    data = sorted((Path(reg.root) / "manifests").glob("*.parquet"))
    data[1].unlink()
    r = _proc("list", "-r", reg.root)
    assert r.returncode == 2 and "data file" in r.stderr and data[1].name in r.stderr, (r.returncode, r.stderr)
    v = _cli("verify", "-r", reg.root, "--json")
    assert v.returncode == 1 and any("data file" in p for p in json.loads(v.stdout)["problems"])


def test_unaccounted_blob_beside_intact_log(tmp_path):
    reg = _registry(tmp_path, 1)
    stray = tmp_path / "stray.bin"
    stray.write_bytes(b"a scene whose commit is gone" * 10)
    from vid2sim.registry.blobs import sha256_file

    sha = sha256_file(stray)[0]
    reg.blobs.put_file(stray, sha)  # stored without an intent: what a lost commit leaves behind
    problems = reg.verify()
    assert len(problems) == 1 and sha in problems[0]
    with pytest.raises(HistoryLost, match="1 blob"):
        reg.gc(grace_s=0)
    assert reg.gc(grace_s=0, force=True) == [sha]
    assert reg.verify() == []


def test_killed_add_leaves_an_intent_gc_cleans_without_force(tmp_path):
    reg = _registry(tmp_path, 1)
    from vid2sim.registry import validate_bundle

    arts, _ = reg._store_blobs(validate_bundle(make_bundle(tmp_path / "k", "k", seed=5)))  # then "killed"
    assert reg.verify() == []  # an add in flight is not lost history
    removed = set(reg.gc(grace_s=0))
    assert removed and removed <= {a.sha256 for a in arts}
    assert reg.blobs.intents() == [] and reg.verify() == []


def test_read_only_commands_never_create_a_registry(tmp_path):
    typo = tmp_path / "regsitry"
    for args in (["list"], ["show", "a"], ["history"], ["verify"], ["gc", "--dry-run"], ["query", "select 1"]):
        r = _cli(*args, "-r", str(typo))
        assert r.returncode == 2 and "no registry at" in r.stderr, (args, r.stderr)
        assert not typo.exists()
    with pytest.raises(RegistryNotFound):
        Registry(typo).list()
    afile = tmp_path / "file.txt"
    afile.write_text("x")
    r = _cli("list", "-r", str(afile))
    assert r.returncode == 2 and "is a file" in r.stderr


def _corrupt(reg: Registry, sha: str) -> None:
    p = reg.blobs.path(sha)
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0xFF
    p.write_bytes(bytes(data))


def test_readd_and_shared_content_repair_a_corrupt_blob(tmp_path):
    reg = _registry(tmp_path, 1)
    splats = reg.show("s0").artifact("splats.ply").sha256
    _corrupt(reg, splats)
    assert reg.add_result(tmp_path / "b0").noop  # same content: no new version...
    assert reg.verify() == []  # ...but the stored bytes were checked and rewritten
    collision = reg.show("s0").artifact("collision.ply").sha256
    _corrupt(reg, collision)
    other = reg.add(make_bundle(tmp_path / "c", "other", seed=3))  # shares collision.ply bytes
    assert other.artifact("collision.ply").sha256 == collision and reg.verify() == []
    assert (reg.checkout("s0", dest=tmp_path / "co") / "collision.ply").is_file()


def test_verify_repair_from_bundle_folder(tmp_path):
    reg = _registry(tmp_path, 2)
    s0 = reg.show("s0")
    _corrupt(reg, s0.artifact("splats.ply").sha256)
    reg.blobs.path(s0.artifact("preview.png").sha256).unlink()
    r = _cli("verify", "-r", reg.root, "--repair")
    assert r.returncode == 2 and "--from" in r.stderr
    r = _cli("verify", "-r", reg.root, "--repair", "--from", str(tmp_path / "b1"), "--json")
    assert r.returncode == 1 and len(json.loads(r.stdout)["problems"]) == 2  # b1 holds other bytes
    r = _cli("verify", "-r", reg.root, "--repair", "--from", str(tmp_path / "b0"), "--json")
    out = json.loads(r.stdout)
    assert r.returncode == 0 and out["ok"] and len(out["repaired"]) == 2, r.output
    assert reg.verify() == []


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_noop_flag_right_under_concurrent_adds(tmp_path):
    import multiprocessing as mp

    from registry_fixtures import cli_add_worker

    reg = _registry(tmp_path, 1)
    same = str(make_bundle(tmp_path / "same", "same", seed=11))
    own = [str(make_bundle(tmp_path / f"own{i}", f"own{i}", seed=20 + i)) for i in range(2)]
    jobs = [same] * 2 + own
    ctx = mp.get_context("spawn")
    with ctx.Manager() as m:
        barrier = m.Barrier(len(jobs))
        with ctx.Pool(len(jobs)) as pool:
            out = pool.starmap(cli_add_worker, [(reg.root, b, barrier) for b in jobs])
    assert sorted(o["noop"] for o in out[:2]) == [False, True]  # one commit of the shared bundle
    assert not any(o["noop"] for o in out[2:])
    assert Registry(reg.root).version == 1 + 3  # s0, then three commits


def test_checkout_dest_that_is_a_file_is_one_line(tmp_path):
    reg = _registry(tmp_path, 1)
    f = tmp_path / "taken"
    f.write_text("x")
    r = _cli("checkout", "s0", "--dest", str(f), "-r", reg.root)
    assert r.returncode == 2 and "is a file" in r.stderr and f.read_text() == "x"
