"""Fault injection: every case against a copy of a registry of a few hundred scenes.

    .venv/bin/python benchmarks/registry_faults.py [--scenes 300] [--root DIR]

Builds one registry of --scenes small real bundles (real blobs, real Delta log), then for each
case: copies it, injects the fault (deletes/truncates/garbles real log files, corrupts real blobs,
races real committers, feeds hostile SQL or input), runs the commands a user would run next
(the read, then `gc --grace-seconds 0`), and counts what was destroyed: scenes whose artifacts
are no longer all present and intact, and blobs of the original registry that are gone or corrupt.
Prints a table: case, what the user sees (exit code + first line), scenes lost, blobs lost.
--quick: a registry of 30 scenes (smoke run).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

TESTS = Path(__file__).resolve().parent.parent / "tests"
sys.path.insert(0, str(TESTS))
sys.path.insert(0, str(Path(__file__).resolve().parent))

LOG = Path("manifests") / "_delta_log"


def cli(*args: str) -> tuple[int, str]:
    """`vid2sim registry ARGS` in-process: (exit code, first line the user sees)."""
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    r = CliRunner().invoke(app, ["registry", *args])
    text = (r.stderr or "") + (r.stdout or "")
    first = next((ln.strip() for ln in text.splitlines() if ln.strip()), "")
    return r.exit_code, first[:150]


def build(root: Path, bundles: Path, n: int) -> dict:
    """Registry of `n` scenes; returns {scene_id: {artifact sha256: size}}."""
    from registry_fixtures import make_bundle

    from vid2sim.registry import Registry

    reg = Registry(root)
    for i in range(n):
        reg.add(make_bundle(bundles / f"b{i:04d}", f"scene-{i:04d}", group=f"walk-{i // 10}", seed=i,
                            n_splats=200))
    return {r.scene_id: {a.sha256: a.size for a in r.artifacts} for r in reg.list()}


def damage(original: dict, root: Path) -> tuple[int, int]:
    """(scenes lost, blobs lost): originals whose blobs are missing or no longer hash right."""
    from vid2sim.registry.blobs import LocalBlobStore

    store = LocalBlobStore(root / "blobs")
    shas = {s: z for arts in original.values() for s, z in arts.items()}
    bad = {s for s, z in shas.items() if not store.intact(s, z)}
    return sum(any(s in bad for s in arts) for arts in original.values()), len(bad)


def log_file(root: Path, v: int) -> Path:
    return root / LOG / f"{v:020d}.json"


def corrupt(root: Path, original: dict, scene: str) -> str:
    """Flip one byte of a blob only `scene` uses (shared ones would be flipped twice by two calls)."""
    shared = {s for sid, arts in original.items() if sid != scene for s in arts}
    sha = sorted(set(original[scene]) - shared)[0]
    p = root / "blobs" / sha[:2] / sha[2:]
    data = bytearray(p.read_bytes())
    data[len(data) // 2] ^= 0xFF
    p.write_bytes(bytes(data))
    return sha


def read_then_gc(root: Path, read: tuple[str, ...] = ("list",)) -> str:
    code, line = cli(*read, "-r", str(root))
    gc_code, gc_line = cli("gc", "-r", str(root), "--grace-seconds", "0")
    return f"{' '.join(read)}: exit {code} `{line}`; gc: exit {gc_code} `{gc_line}`"


# ----------------------------------------------------------------------------- cases
def case_log_deleted(root: Path, ctx: dict) -> str:
    shutil.rmtree(root / LOG)
    return read_then_gc(root)


def case_manifests_deleted(root: Path, ctx: dict) -> str:
    shutil.rmtree(root / "manifests")
    return read_then_gc(root)


def case_log_truncated(root: Path, ctx: dict) -> str:
    log_file(root, ctx["n"] // 2).write_bytes(b"")
    return read_then_gc(root, ("history",))


def case_log_file_deleted(root: Path, ctx: dict) -> str:
    log_file(root, ctx["n"] // 2).unlink()
    return read_then_gc(root)


def case_log_garbled(root: Path, ctx: dict) -> str:
    log_file(root, ctx["n"] // 3).write_text("{not json\n")
    return read_then_gc(root)


def case_data_file_deleted(root: Path, ctx: dict) -> str:
    from deltalake import DeltaTable

    active = sorted(DeltaTable(str(root / "manifests")).file_uris())  # one the snapshot needs
    Path(active[0].removeprefix("file://")).unlink()
    return read_then_gc(root)


def case_stray_blob(root: Path, ctx: dict) -> str:
    from vid2sim.registry.blobs import LocalBlobStore, sha256_file

    f = root.parent / f"{root.name}-stray.bin"
    f.write_bytes(b"blob of a commit whose log entry is gone" * 100)
    LocalBlobStore(root / "blobs").put_file(f, sha256_file(f)[0])
    return read_then_gc(root, ("verify",))


def case_corrupt_then_readd(root: Path, ctx: dict) -> str:
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    corrupt(root, ctx["original"], "scene-0007")
    r = CliRunner().invoke(app, ["registry", "add", str(ctx["bundles"] / "b0007"), "-r", str(root), "--json"])
    noop = json.loads(r.stdout).get("noop") if r.exit_code == 0 else None
    v_code, v_line = cli("verify", "-r", str(root))
    return f"re-add: exit {r.exit_code}, noop={noop}; verify: exit {v_code} `{v_line}`"


def case_corrupt_then_repair(root: Path, ctx: dict) -> str:
    corrupt(root, ctx["original"], "scene-0011")
    corrupt(root, ctx["original"], "scene-0012")
    before = cli("verify", "-r", str(root))
    code, line = cli("verify", "-r", str(root), "--repair", "--from", str(ctx["bundles"]))
    return f"verify: exit {before[0]} `{before[1][:48]}...`; --repair --from: exit {code} `{line}`"


def case_killed_add(root: Path, ctx: dict) -> str:
    from registry_fixtures import make_bundle

    from vid2sim.formats.bundle import validate_bundle
    from vid2sim.registry import Registry

    b = make_bundle(root.parent / f"{root.name}-killed", "killed-scene", seed=99_999)
    Registry(root)._store_blobs(validate_bundle(b))  # blobs + intent, then no commit ("killed")
    return read_then_gc(root, ("verify",))


def case_concurrent_noop(root: Path, ctx: dict) -> str:
    from registry_fixtures import make_bundle

    from vid2sim.registry import Registry

    new = make_bundle(root.parent / f"{root.name}-new", "scene-new", seed=50_000, n_splats=200)
    jobs, out, go = [new] * 3 + [ctx["bundles"] / "b0003"], [], threading.Barrier(4)

    def worker(b: Path) -> None:
        go.wait()
        out.append(Registry(root).add_result(b).noop)

    threads = [threading.Thread(target=worker, args=(b,)) for b in jobs]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return f"3 racing adds of one new scene + 1 unchanged re-add: noop {sorted(out)} (right: 1 False)"


def case_typo_root(root: Path, ctx: dict) -> str:
    typo = root.parent / f"{root.name}-typo"
    code, line = cli("list", "-r", str(typo))
    return f"list: exit {code} `{line}`; created: {typo.exists()}"


def case_root_is_file(root: Path, ctx: dict) -> str:
    f = root.parent / f"{root.name}-file"
    f.write_text("x")
    return "list: exit %d `%s`" % cli("list", "-r", str(f))


def case_query(sql: str, *extra: str) -> Callable[[Path, dict], str]:
    def run(root: Path, ctx: dict) -> str:
        code, line = cli("query", sql, "-r", str(root), *extra)
        return f"exit {code} `{line}`"
    return run


def case_nan_splats(root: Path, ctx: dict) -> str:
    import io

    import numpy as np
    from plyfile import PlyData

    b = root.parent / f"{root.name}-nan"
    shutil.copytree(ctx["bundles"] / "b0001", b)
    ply = PlyData.read(io.BytesIO((b / "splats.ply").read_bytes()))
    ply["vertex"].data["opacity"][0] = np.nan
    ply.write(str(b / "splats.ply"))
    return "add: exit %d `%s`" % cli("add", str(b), "-r", str(root))


# ----------------------------------------------------------------------------- second round
ADD_LOOP = """
import sys
from vid2sim.registry.store import Registry
reg = Registry(sys.argv[1])
for b in sys.argv[2:]:
    print("added", reg.add(b).ref, flush=True)
"""

GC_LOOP = """
import os, sys
from typer.testing import CliRunner
from vid2sim.cli.app import app
runs = 0
while True:
    last = os.path.exists(sys.argv[2])
    r = CliRunner().invoke(app, ["registry", "gc", "-r", sys.argv[1], "--grace-seconds", "0"])
    assert r.exit_code == 0, r.output
    runs += 1
    if last:
        break
print(runs, flush=True)
"""


def _spawn(script: str, *args: str) -> subprocess.Popen:
    path = os.pathsep.join([str(TESTS), str(TESTS.parent), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path}
    return subprocess.Popen([sys.executable, "-c", script, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)


def case_gc_races_adds(root: Path, ctx: dict) -> str:
    """`gc --grace-seconds 0` in a loop (a real process) beside 3 processes adding 10 scenes each."""
    from registry_fixtures import make_bundle

    from vid2sim.registry import Registry

    work = root.parent / f"{root.name}-race"
    jobs = [[str(make_bundle(work / f"w{w}-{i}", f"race-{w}-{i}", seed=70_000 + 10 * w + i, n_splats=2000))
             for i in range(10)] for w in range(3)]
    stop = work / "stop"
    gc_proc = _spawn(GC_LOOP, str(root), str(stop))
    adders = [_spawn(ADD_LOOP, str(root), *job) for job in jobs]
    outs = [p.communicate(timeout=600) for p in adders]
    stop.touch()
    gc_out, gc_err = gc_proc.communicate(timeout=600)
    added = sum(out.count("added") for out, _ in outs)
    reg = Registry(root)
    lost = [r.ref for r in reg.list() if r.scene_id.startswith("race-")
            and not all(reg.blobs.intact(a.sha256, a.size) for a in r.artifacts)]
    v_code, v_line = cli("verify", "-r", str(root))
    return (f"{added}/30 adds committed, gc ran {gc_out.strip() or gc_err.strip()[-80:]} times, "
            f"committed scenes with lost blobs: {len(lost)}; verify: exit {v_code} `{v_line}`")


def case_bad_grace(root: Path, ctx: dict) -> str:
    return "gc --grace-seconds -1: exit %d `%s`" % cli("gc", "-r", str(root), "--grace-seconds", "-1")


def case_time_travel_gap(root: Path, ctx: dict) -> str:
    latest = ctx["n"]
    log_file(root, ctx["n"] // 2).write_bytes(b"")
    code, line = cli("list", "-r", str(root), "--as-of", str(latest))
    s_code, s_line = cli("split", "-r", str(root), "--as-of", str(latest))
    return f"list --as-of {latest}: exit {code} `{line}`; split --as-of: exit {s_code}"


def case_checkout_tampered(root: Path, ctx: dict) -> str:
    dest = root.parent / f"{root.name}-co"
    cli("checkout", "scene-0005", "-r", str(root), "--dest", str(dest))
    with open(dest / "splats.ply", "r+b") as f:
        f.seek(-8, os.SEEK_END)
        f.write(b"tampered")
    (dest / "walkable.npz").unlink()
    code, line = cli("checkout", "scene-0005", "-r", str(root), "--dest", str(dest))
    from vid2sim.formats.bundle import validate_bundle

    validate_bundle(dest)
    return f"re-checkout: exit {code}; splats.ply and walkable.npz rewritten, bundle validates"


def case_not_a_registry(root: Path, ctx: dict) -> str:
    code, line = cli("list", "-r", str(root / "manifests"))
    v_code, _ = cli("verify", "-r", str(root / "blobs"))
    return f"list -r manifests/: exit {code} `{line}`; verify -r blobs/: exit {v_code}"


def case_tag_typo(root: Path, ctx: dict) -> str:
    typo = root.parent / f"{root.name}-typo"
    code, line = cli("tag", "scene-0001", "city", "-r", str(typo))
    return f"tag: exit {code} `{line}`; created: {typo.exists()}"


def case_secret_url(root: Path, ctx: dict) -> str:
    b = root.parent / f"{root.name}-secret"
    shutil.copytree(ctx["bundles"] / "b0002", b)
    scene = json.loads((b / "scene.json").read_text())
    scene["source"]["uri"] = "https://videos.example/walk.mp4?client_secret=s3cr3t&sig=abc#access_token=t0k"
    (b / "scene.json").write_text(json.dumps(scene))
    code, line = cli("add", str(b), "-r", str(root))
    return f"add: exit {code} `{line}`; secret printed: {'s3cr3t' in line or 't0k' in line}"


def case_walkable_bomb(root: Path, ctx: dict) -> str:
    import resource

    from bomb_files import write_walkable_bomb

    b = root.parent / f"{root.name}-bomb"
    shutil.copytree(ctx["bundles"] / "b0003", b)
    write_walkable_bomb(b / "walkable.npz", 20_000, 20_000)  # 400M cells in ~400 KB
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    code, line = cli("add", str(b), "-r", str(root))
    grew = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    size_kb = (b / "walkable.npz").stat().st_size // 1024
    return f"add ({size_kb} KB npz): exit {code} `{line}`; peak memory +{grew:.0f} MB"


def case_paths(*args: str) -> Callable[[Path, dict], str]:
    def run(root: Path, ctx: dict) -> str:
        blocker = root.parent / f"{root.name}-file"
        blocker.write_text("x")
        argv = [a.replace("ROOT", str(root)).replace("FILE", str(blocker)) for a in args]
        return "exit %d `%s`" % cli(*argv)
    return run


def case_ill_typed_scene_json(root: Path, ctx: dict) -> str:
    b = root.parent / f"{root.name}-typed"
    shutil.copytree(ctx["bundles"] / "b0004", b)
    scene = json.loads((b / "scene.json").read_text())
    scene["metrics"] = {"psnr": "high"}
    scene["tags"] = "city"
    (b / "scene.json").write_text(json.dumps(scene))
    return "add: exit %d `%s`" % cli("add", str(b), "-r", str(root))


CASES: dict[str, Callable[[Path, dict], str]] = {
    "manifests/_delta_log deleted": case_log_deleted,
    "manifests/ deleted": case_manifests_deleted,
    "middle log file truncated to 0 B": case_log_truncated,
    "middle log file deleted": case_log_file_deleted,
    "log file garbled": case_log_garbled,
    "active manifest data file deleted": case_data_file_deleted,
    "blob nothing references": case_stray_blob,
    "add killed before commit": case_killed_add,
    "corrupt blob, same bundle re-added": case_corrupt_then_readd,
    "2 corrupt blobs, verify --repair": case_corrupt_then_repair,
    "concurrent adds, noop flag": case_concurrent_noop,
    "query read_text('/etc/shadow')": case_query("select content from read_text('/etc/shadow')"),
    "query COPY TO file": case_query("copy (select * from scenes) to '/tmp/vid2sim-leak.csv'"),
    "query ATTACH + CREATE": case_query("attach '/tmp/vid2sim-x.db' as x; create table x.t as select 1"),
    "query INSTALL httpfs": case_query("install httpfs"),
    "query range(1e8) --json": case_query("select * from range(100000000)", "--json", "--max-rows", "1000"),
    "mistyped --registry": case_typo_root,
    "--registry is a file": case_root_is_file,
    "NaN opacity in splats.ply": case_nan_splats,
    "gc --grace-seconds 0 racing 30 adds (real processes)": case_gc_races_adds,
    "gc --grace-seconds -1": case_bad_grace,
    "time travel past an emptied log entry": case_time_travel_gap,
    "checkout: tampered splats.ply, deleted walkable.npz": case_checkout_tampered,
    "--registry at manifests/ or blobs/": case_not_a_registry,
    "tag on a mistyped --registry": case_tag_typo,
    "secrets in scene.json source.uri": case_secret_url,
    "walkable.npz declaring 400M cells": case_walkable_bomb,
    "query 2 GB of rows --memory 64MB": case_query("select repeat('x', 100000) as s from range(20000)",
                                                   "--memory", "64MB", "--max-rows", "100000"),
    "query --memory 12XB": case_query("select 1", "--memory", "12XB"),
    "compact on a mistyped path": case_paths("compact", "-r", "ROOT-nowhere"),
    "checkout --dest below a file": case_paths("checkout", "scene-0001", "-r", "ROOT", "--dest", "FILE/co"),
    "memory:// registry root": case_paths("list", "-r", "memory://vid2sim"),
    "ill-typed scene.json fields": case_ill_typed_scene_json,
}


def main() -> None:
    from common import Run, add_run_args

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--root", type=Path, default=None, help="work folder (default: a temp dir)")
    ap.add_argument("--quick", action="store_true", help="a registry of 30 scenes")
    add_run_args(ap)
    args = ap.parse_args()
    if args.quick and args.scenes == 300:
        args.scenes = 30
    with Run("registry_faults", args) as run:
        bench(run, args)


def bench(run, args: argparse.Namespace) -> None:
    work = Path(args.root or tempfile.mkdtemp(prefix="vid2sim-faults-"))
    t = time.perf_counter()
    original = build(work / "base", work / "bundles", args.scenes)
    secs = run.record(f"build a registry of {args.scenes} scenes", "seconds", time.perf_counter() - t, "s")
    print(f"built a registry of {len(original)} scenes in {secs:.0f} s; $W = {work}\n")
    print("| case | what the user sees | scenes lost | blobs lost | s |")
    print("|---|---|---|---|---|")
    for i, (name, fn) in enumerate(CASES.items()):
        root = work / f"case-{i:02d}"
        shutil.copytree(work / "base", root)
        t = time.perf_counter()
        seen = fn(root, {"original": original, "bundles": work / "bundles", "n": args.scenes})
        seen = seen.replace(str(work), "$W")
        scenes, blobs = damage(original, root)
        secs = time.perf_counter() - t
        run.record_all(name, {"what the user sees": seen, "scenes lost": scenes, "blobs lost": blobs,
                              "seconds": secs}, {"seconds": "s"}, {"scenes": args.scenes})
        print(f"| {name} | {seen.replace('|', '/')} | {scenes} | {blobs} | {secs:.1f} |",
              flush=True)
    if args.root is None:
        shutil.rmtree(work, ignore_errors=True)

if __name__ == "__main__":
    main()
