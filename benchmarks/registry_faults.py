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
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
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
