"""Registry reliability on real files and real processes.

- `gc` at any grace period (0 included) beside concurrent `add`s: no committed scene loses a
  blob, no add dies on its own temp file, and the leftovers of killed adds still go.
- Bad grace periods are a named error.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from registry_fixtures import make_bundle

from vid2sim.registry import Registry, RegistryError

TESTS_DIR = Path(__file__).resolve().parent
PROJECT = TESTS_DIR.parent

ADD_LOOP = """
import sys, traceback
from vid2sim.registry.store import Registry
reg = Registry(sys.argv[1])
reg.version
print("ready", flush=True)
try:
    for b in sys.argv[2:]:
        rec = reg.add(b)
        print("added", rec.ref, flush=True)
except BaseException:
    traceback.print_exc()
    sys.exit(1)
"""

GC_LOOP = """
import json, os, sys, traceback
from vid2sim.registry.store import Registry
reg = Registry(sys.argv[1])
stop = sys.argv[2]
runs, removed = 0, []
print("ready", flush=True)
try:
    while True:
        last = os.path.exists(stop)
        removed += reg.gc(grace_s=0)
        runs += 1
        if last:
            break
except BaseException:
    traceback.print_exc()
    sys.exit(1)
print(json.dumps({"runs": runs, "removed": removed}), flush=True)
"""

STORE_THEN_DIE = """
import sys
from vid2sim.registry import validate_bundle
from vid2sim.registry.store import Registry
reg = Registry(sys.argv[1])
for b in sys.argv[2:]:
    reg._store_blobs(validate_bundle(b))  # an add killed after storing its blobs, before its commit
"""


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS_DIR), str(PROJECT),
                                                         os.environ.get("PYTHONPATH", "")])}


def _spawn(script: str, err: Path, *args: str) -> subprocess.Popen:
    """A real process; stdout is read through the pipe (one pipe: `finish` loses no line)."""
    return subprocess.Popen([sys.executable, "-c", script, *args], stdout=subprocess.PIPE,
                            stderr=err.open("w"), text=True, env=_env())


def _finish(p: subprocess.Popen, err: Path, timeout: float) -> tuple[str, str]:
    out = p.stdout.read()  # the rest after "ready" (same buffered reader: nothing skipped)
    p.wait(timeout=timeout)
    return out, err.read_text()


@pytest.mark.timeout(240)
def test_gc_grace_zero_beside_concurrent_adds(tmp_path):
    root = str(tmp_path / "reg")
    reg = Registry(root)
    reg.add(make_bundle(tmp_path / "first", "first"))
    n_workers, n_each = 3, 8
    jobs = [[str(make_bundle(tmp_path / f"w{w}-{i}", f"w{w}-s{i}", seed=100 * w + i, n_splats=4000))
             for i in range(n_each)] for w in range(n_workers)]
    # leftovers of killed adds: the blobs of half the bundles the workers will add (identical
    # content: gc's orphans become referenced again mid-run), and of bundles nobody adds
    dead = [str(make_bundle(tmp_path / f"dead{i}", f"dead{i}", seed=900 + i)) for i in range(3)]
    readd = [b for w in jobs for b in w[::2]]
    subprocess.run([sys.executable, "-c", STORE_THEN_DIE, root, *readd, *dead], check=True, env=_env(),
                   timeout=120)
    dead_blobs = {a for b in dead for a in _shas(b)} - {a for w in jobs for b in w for a in _shas(b)}
    assert dead_blobs and dead_blobs <= {b.sha256 for b in reg.blobs.list()}

    stop = tmp_path / "stop"
    gc_proc = _spawn(GC_LOOP, tmp_path / "gc.err", root, str(stop))
    adders = [_spawn(ADD_LOOP, tmp_path / f"add{w}.err", root, *jobs[w]) for w in range(n_workers)]
    for p in [gc_proc, *adders]:
        assert p.stdout.readline().strip() == "ready"
    outs = [_finish(p, tmp_path / f"add{w}.err", 180) for w, p in enumerate(adders)]
    stop.touch()
    gc_out, gc_err = _finish(gc_proc, tmp_path / "gc.err", 120)
    for p, (out, err) in zip(adders, outs):
        assert p.returncode == 0, err[-3000:]
    assert gc_proc.returncode == 0, gc_err[-3000:]
    summary = json.loads(gc_out.strip().splitlines()[-1])
    assert summary["runs"] >= 2

    reg = Registry(root)
    added = {line.split()[1].split("@")[0] for out, _ in outs for line in out.splitlines()
             if line.startswith("added")}
    want = {f"w{w}-s{i}" for w in range(n_workers) for i in range(n_each)}
    assert added == want
    assert {r.scene_id for r in reg.list()} == want | {"first"}
    assert reg.verify() == []  # every committed scene's blobs present and intact, nothing stray
    for r in reg.list():
        for a in r.artifacts:
            assert reg.blobs.intact(a.sha256, a.size), f"{r.ref}:{a.name}"
    stored = {b.sha256 for b in reg.blobs.list() if not b.is_temp}
    assert not dead_blobs & stored  # the killed adds' leftovers went
    assert reg.blobs.intents() == [] and not [b for b in reg.blobs.list() if b.is_temp]


@pytest.mark.parametrize("grace", [-1.0, float("nan"), float("-inf")])
def test_gc_rejects_negative_or_nan_grace(tmp_path, grace):
    from vid2sim.registry.errors import BadGracePeriod

    reg = Registry(tmp_path / "reg")
    reg.add(make_bundle(tmp_path / "a", "a"))
    before = {b.sha256 for b in reg.blobs.list()}
    with pytest.raises(BadGracePeriod, match="grace"):
        reg.gc(grace_s=grace)
    assert issubclass(BadGracePeriod, RegistryError)
    assert {b.sha256 for b in reg.blobs.list()} == before
    assert reg.gc(grace_s=float("inf")) == []  # inf: keeps everything


def test_gc_cli_rejects_bad_grace(tmp_path):
    reg = Registry(tmp_path / "reg")
    reg.add(make_bundle(tmp_path / "a", "a"))
    for bad in ("-5", "nan"):
        r = subprocess.run([sys.executable, "-m", "vid2sim.cli", "registry", "gc", "-r", reg.root,
                            "--grace-seconds", bad], capture_output=True, text=True, timeout=120, env=_env())
        assert r.returncode == 2 and "grace" in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_gc_never_deletes_a_live_writers_temp_file(tmp_path):
    """A temp file whose writer is alive stays, however old; a dead writer's goes."""
    reg = Registry(tmp_path / "reg")
    reg.add(make_bundle(tmp_path / "a", "a"))
    from vid2sim.registry.blobs import temp_name

    tmp_dir = Path(reg.root) / "blobs" / "tmp"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = tmp_dir / temp_name(pid=sleeper.pid)
        live.write_bytes(b"half a blob being written")
        gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True, check=True).stdout.strip()
        dead = tmp_dir / temp_name(pid=int(gone))
        dead.write_bytes(b"half a blob of a killed writer")
        old = time.time() - 10 * 24 * 3600
        for p in (live, dead):
            os.utime(p, (old, old))
        removed = reg.gc(grace_s=0)
        assert live.exists() and not dead.exists()
        assert removed == [f"tmp/{dead.name}"]
    finally:
        sleeper.kill()
        sleeper.wait()
    assert reg.gc(grace_s=0) == [f"tmp/{live.name}"]  # its writer is gone now


def test_blobs_left_in_the_trash_by_a_killed_gc_come_back(tmp_path):
    reg = Registry(tmp_path / "reg")
    rec = reg.add(make_bundle(tmp_path / "a", "a"))
    sha = rec.artifact("splats.ply").sha256
    # a gc killed between moving a blob aside and re-checking it
    subprocess.run([sys.executable, "-c", "import sys; from vid2sim.registry.store import Registry; "
                    "Registry(sys.argv[1]).blobs.trash(sys.argv[2])", reg.root, sha], check=True, env=_env(),
                   timeout=120)
    problems = reg.verify()
    assert len(problems) == 1 and sha in problems[0] and "blobs/trash" in problems[0]
    assert reg.gc(grace_s=0) == []  # puts it back, deletes nothing
    assert reg.verify() == [] and reg.blobs.trashed() == []
    assert (reg.checkout("a", dest=tmp_path / "co") / "splats.ply").is_file()


def _shas(bundle: str) -> set[str]:
    from vid2sim.registry import validate_bundle
    from vid2sim.registry.blobs import sha256_file

    return {sha256_file(p)[0] for p in validate_bundle(bundle).artifacts.values()}


# ---------------------------------------------------------------------------- every read path checks

LOG = Path("manifests") / "_delta_log"


def _cli(*args: str):
    """`vid2sim registry ARGS` in-process (result has returncode, stdout, stderr)."""
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    r = CliRunner().invoke(app, ["registry", *args])
    r.returncode = r.exit_code
    return r


def _four(tmp_path: Path) -> Registry:
    reg = Registry(tmp_path / "reg")  # versions: 0 create, 1..4 one add each
    for i in range(4):
        reg.add(make_bundle(tmp_path / f"b{i}", f"s{i}", seed=i, group=f"g{i}"))
    return reg


@pytest.mark.parametrize("damage", ["empty", "missing"])
def test_time_travel_checks_log_continuity(tmp_path, damage):
    from vid2sim.registry import HistoryLost

    reg = _four(tmp_path)
    assert [r.scene_id for r in reg.list(as_of=3)] == ["s0", "s1", "s2"]
    entry = Path(reg.root) / LOG / f"{2:020d}.json"
    saved = entry.read_bytes()
    entry.write_bytes(b"") if damage == "empty" else entry.unlink()
    why = "version 2 is empty" if damage == "empty" else "version 2 is missing"
    fresh = Registry(reg.root)
    for as_of in (1, 3, 4, "2100-01-01T00:00:00"):
        for read in (lambda: fresh.list(as_of=as_of), lambda: fresh.query("select * from latest", as_of=as_of),
                     lambda: fresh.split(as_of=as_of), lambda: fresh.history(as_of=as_of)):
            with pytest.raises(HistoryLost, match=why):
                read()
    for cmd in (["list"], ["query", "select scene_id from latest"], ["split"]):
        r = _cli(*cmd, "-r", reg.root, "--as-of", "3")
        assert r.returncode == 2 and why in r.stderr and "Traceback" not in r.stderr, (cmd, r.stderr)
    entry.write_bytes(saved)
    assert [r.scene_id for r in Registry(reg.root).list(as_of=3)] == ["s0", "s1", "s2"]


def test_time_travel_to_a_version_that_does_not_exist_is_named(tmp_path):
    reg = _four(tmp_path)
    for v in (5, 99, -1):
        with pytest.raises(ValueError, match="no such registry version"):
            reg.list(as_of=v)


def test_checkout_reverifies_an_existing_destination(tmp_path):
    from vid2sim.registry.blobs import sha256_file

    reg = _four(tmp_path)
    rec = reg.show("s1")
    dest = reg.checkout("s1", dest=tmp_path / "co")
    want = {a.name: a.sha256 for a in rec.artifacts}
    splats = bytearray((dest / "splats.ply").read_bytes())
    splats[len(splats) // 2] ^= 0xFF  # bit rot, same size
    (dest / "splats.ply").write_bytes(bytes(splats))
    (dest / "preview.png").write_bytes((dest / "preview.png").read_bytes()[:10])  # truncated
    (dest / "walkable.npz").unlink()
    (dest / "scene.json").write_text("{}")  # edited by hand
    (dest / "notes.txt").write_text("mine")  # not an artifact: left alone
    assert reg.checkout("s1", dest=dest) == dest
    assert {n: sha256_file(dest / n)[0] for n in want} == want
    assert (dest / "notes.txt").read_text() == "mine"
    assert not [p for p in dest.iterdir() if ".tmp-" in p.name]
    (dest / "collision.ply").write_bytes(b"")
    r = _cli("checkout", "s1", "--dest", str(dest), "-r", reg.root)
    assert r.returncode == 0, r.stderr
    assert sha256_file(dest / "collision.ply")[0] == want["collision.ply"]
    # a corrupt blob is refused, not copied into the checkout
    blob = reg.blobs.path(want["scene.json"])
    blob.write_bytes(blob.read_bytes()[:-1] + b" ")
    (dest / "scene.json").write_text("{}")
    with pytest.raises(RegistryError, match="corrupt"):
        reg.checkout("s1", dest=dest)
    assert (dest / "scene.json").read_text() == "{}" and not [p for p in dest.iterdir() if ".tmp-" in p.name]


def test_checkout_over_another_registrys_scene_names_both(tmp_path):
    ours, theirs = Registry(tmp_path / "ours"), Registry(tmp_path / "theirs")
    ours.add(make_bundle(tmp_path / "b0", "s1", seed=0))
    theirs.add(make_bundle(tmp_path / "b1", "s1", seed=1))  # same id@version, other content
    dest = theirs.checkout("s1", dest=tmp_path / "co")
    before = {p.name: p.read_bytes() for p in dest.iterdir()}
    with pytest.raises(RegistryError, match="holds something else") as err:
        ours.checkout("s1", dest=dest)
    assert theirs.root in str(err.value) and ours.root in str(err.value) and "s1@1" in str(err.value)
    assert {p.name: p.read_bytes() for p in dest.iterdir()} == before  # nothing overwritten


def test_a_checkout_of_a_registry_made_anew_at_the_same_place_is_replaced(tmp_path):
    import shutil

    from vid2sim.registry.blobs import sha256_file
    from vid2sim.registry.store import CHECKOUT_MARKER

    root = tmp_path / "reg"
    Registry(root).add(make_bundle(tmp_path / "b0", "s1", seed=0))
    dest = Registry(root).checkout("s1", dest=tmp_path / "co")
    (dest / "simready-old.ply").write_bytes(b"a cache of the old content")
    shutil.rmtree(root)  # the registry deleted and ingested again: s1@1 is other content now
    reg = Registry(root)
    reg.add(make_bundle(tmp_path / "b1", "s1", seed=1))
    rec = reg.show("s1")
    assert reg.checkout("s1", dest=dest) == dest
    assert {a.name: sha256_file(dest / a.name)[0] for a in rec.artifacts} == {a.name: a.sha256 for a in rec.artifacts}
    assert json.loads((dest / CHECKOUT_MARKER).read_text())["content_hash"] == rec.content_hash
    assert not (dest / "simready-old.ply").exists()  # the stale folder went whole
    assert not [p for p in tmp_path.iterdir() if ".stale-" in p.name or ".tmp-" in p.name]


def test_a_folder_that_is_not_a_registry_is_a_named_error(tmp_path):
    from vid2sim.registry import RegistryNotFound

    plain = tmp_path / "photos"
    plain.mkdir()
    (plain / "a.jpg").write_bytes(b"not a registry")
    empty = tmp_path / "empty"
    empty.mkdir()
    for folder in (plain, empty):
        before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
        reg = Registry(folder)
        for read in (reg.list, reg.verify, reg.history, lambda: reg.gc(grace_s=0), lambda: reg.compact(),
                     lambda: reg.show("a")):
            with pytest.raises(RegistryNotFound, match="no registry at"):
                read()
        for cmd in (["list"], ["verify"], ["gc", "--grace-seconds", "0"], ["compact"]):
            r = _cli(*cmd, "-r", str(folder))
            assert r.returncode == 2 and "no registry at" in r.stderr and "Traceback" not in r.stderr, (cmd, r.stderr)
        assert sorted(p.relative_to(folder) for p in folder.rglob("*")) == before  # nothing written


def test_mutations_never_create_a_registry(tmp_path):
    from vid2sim.registry import RegistryNotFound

    real = _four(tmp_path)
    typo = tmp_path / "regsitry"
    plain = tmp_path / "plain"
    plain.mkdir()
    for root in (typo, plain):
        reg = Registry(root)
        for change in (lambda: reg.tag("s0", "x"), lambda: reg.untag("s0", "x"),
                       lambda: reg.deprecate("s0", "bad")):
            with pytest.raises(RegistryNotFound, match="no registry at"):
                change()
        for cmd in (["tag", "s0", "x"], ["untag", "s0", "x"], ["deprecate", "s0", "--reason", "bad"]):
            r = _cli(*cmd, "-r", str(root))
            assert r.returncode == 2 and "no registry at" in r.stderr, (cmd, r.stderr)
        assert not typo.exists() and list(plain.iterdir()) == []
    assert real.tag("s0", "x").version == 2  # a real registry still takes them
    added = Registry(typo).add(make_bundle(tmp_path / "n", "n"))  # only add creates one
    assert added.version == 1 and (typo / LOG).is_dir()
