"""Registry benchmark: commit latency, and list / split / query latency with 10,000 scene rows.

    .venv/bin/python benchmarks/registry.py [--adds 40] [--rows 10000] [--batch 500] [--root DIR] [--quick]

Steps: (1) N single `add`s of small real bundles (300 Gaussians) into an empty registry;
(2) bulk-create ROWS scene rows with batched appends (rows reuse real blobs, so verify holds);
(3) list / split / query latency over ROWS scenes, cold (fresh handle) and warm;
(4) single-commit latency (tag, add) with ROWS scenes present, before and after `compact()`
    (steps 1-4 with automatic compaction off, to show what it saves);
(5) --sustained tag commits in a row from the compacted table, automatic compaction off vs on
    (default threshold: RegistryConfig.auto_compact_files).
--quick: 10 adds, 2,000 rows, 30 sustained commits (smoke run).
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from common import Run, add_run_args  # noqa: E402  (benchmarks/common.py)

RUN: Run  # the current run (set in main)


def stats(xs: list[float], case: str = "", config: dict | None = None) -> str:
    """Median / p95 of latencies xs (s) as text; with a case, recorded as rows of RUN too."""
    ms = np.array(xs) * 1e3
    med, p95 = float(np.median(ms)), float(np.percentile(ms, 95))
    if case:
        RUN.record_all(case, {"median_ms": med, "p95_ms": p95, "n": len(ms)}, {"median_ms": "ms", "p95_ms": "ms"},
                       config)
    return f"median {med:8.1f} ms  p95 {p95:8.1f} ms  (n={len(ms)})"


def timed(fn, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def bulk_rows(template, n: int, start: int) -> list[dict]:
    rows = []
    for i in range(start, start + n):
        rec = template.evolve(scene_id=f"bulk-{i:06d}", source_group=f"video-{i % 997:04d}",
                              metrics={"psnr": 18.0 + (i % 13)}, tags=("night",) if i % 4 == 0 else ())
        rows.append(rec.to_row())
    return rows


def sustained(root: Path, n: int, config_cls) -> None:
    """n tag commits in a row on a compacted table, automatic compaction off vs on."""
    from vid2sim.registry.store import Registry

    for label, conf in (("off", config_cls(auto_compact_files=0)), ("on ", config_cls())):
        case = f"{n} tag commits in a row, auto-compaction {label.strip()}"
        reg = Registry(root, config=conf)
        reg.compact()
        v0, lat = reg.version, []
        for i in range(n):
            t = time.perf_counter()
            reg.tag("bulk-000002", f"s{label.strip()}{i}")
            lat.append(time.perf_counter() - t)
        compactions = reg.version - v0 - n
        text = stats(lat, case, {"auto_compact_files": conf.auto_compact_files})
        RUN.record_all(case, {"max_ms": max(lat) * 1e3, "last10_median_ms": statistics.median(lat[-10:]) * 1e3,
                              "compactions": compactions, "files_at_end": reg.manifest.num_files()},
                       {"max_ms": "ms", "last10_median_ms": "ms"}, {"auto_compact_files": conf.auto_compact_files})
        print(f"{n} tag commits, auto-compaction {label}:     {text}  max {max(lat) * 1e3:6.0f} ms  "
              f"last 10 median {statistics.median(lat[-10:]) * 1e3:6.1f} ms  "
              f"({compactions} compactions, {reg.manifest.num_files()} files at the end)")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--adds", type=int, default=40)
    ap.add_argument("--rows", type=int, default=10_000)
    ap.add_argument("--batch", type=int, default=500)
    ap.add_argument("--sustained", type=int, default=120, help="tag commits in a row for step 5")
    ap.add_argument("--root", default=None, help="registry folder (default: a temp dir, removed after)")
    ap.add_argument("--quick", action="store_true", help="10 adds, 2,000 rows, 30 sustained commits")
    add_run_args(ap)
    args = ap.parse_args()
    if args.quick:
        args.adds, args.rows, args.sustained = min(args.adds, 10), min(args.rows, 2000), min(args.sustained, 30)
    global RUN
    with Run("registry", args, libraries=("duckdb", "pyarrow")) as RUN:
        bench(args)


def bench(args: argparse.Namespace) -> None:
    from registry_fixtures import make_bundle

    from vid2sim.registry.store import Registry, RegistryConfig

    tmp = Path(tempfile.mkdtemp(prefix="vid2sim-bench-"))
    root = Path(args.root) if args.root else tmp / "reg"
    try:
        bundles = [make_bundle(tmp / f"b{i}", f"bench-{i:04d}", group=f"g{i % 7}", seed=i)
                   for i in range(args.adds + 20)]
        manual = RegistryConfig(auto_compact_files=0)
        reg = Registry(root, config=manual)
        adds = [b for b in bundles[:args.adds]]
        lat = []
        for b in adds:
            t = time.perf_counter()
            reg.add(b)
            lat.append(time.perf_counter() - t)
        case = f"add, empty registry -> {args.adds} scenes"
        print(f"add (empty registry -> {args.adds} scenes):      {stats(lat, case)}")
        print(f"re-add identical (no-op):                "
              f"{stats(timed(lambda: reg.add(adds[0]), 10), 're-add identical (no-op)')}")

        template = reg.show(f"bench-{0:04d}")
        t = time.perf_counter()
        made = 0
        while made < args.rows - args.adds:
            k = min(args.batch, args.rows - args.adds - made)
            reg.manifest.append_bulk(bulk_rows(template, k, made))
            made += k
        bulk_s = RUN.record(f"bulk-create {made} rows", "seconds", time.perf_counter() - t, "s",
                            {"batch": args.batch})
        print(f"bulk-create {made} rows in batches of {args.batch}: {bulk_s:.1f} s "
              f"(registry version {reg.version})")

        def cold_list():
            assert len(Registry(root, config=manual).list()) >= args.rows

        names = iter(range(10**6))
        more = iter(bundles[args.adds:])
        for label in ("", " (after compact)"):
            at = f", {args.rows} scenes{label}"
            print(f"-- {args.rows} scenes{label}")
            print(f"list cold (fresh handle):                {stats(timed(cold_list, 5), 'list cold' + at)}")
            print(f"list warm:                               {stats(timed(lambda: reg.list(), 5), 'list warm' + at)}")
            print(f"split (seed, 20% test, train 1/5/15/100): "
                  f"{stats(timed(lambda: reg.split(seed=1, train_sizes=(1, 5, 15, 100)), 5), 'split' + at)}")
            filtered = timed(lambda: reg.split(seed=1, tags=('night',), min_metrics={'psnr': 20}), 5)
            print(f"split with tag + psnr filter:            {stats(filtered, 'split with tag + psnr filter' + at)}")
            grouped = timed(lambda: reg.query('select source_group, count(*) from latest group by 1'), 5)
            print(f"query (count latest by group):           {stats(grouped, 'query count latest by group' + at)}")
            print(f"tag commit:                              "
                  f"{stats(timed(lambda: reg.tag('bulk-000001', f't{next(names)}'), 10), 'tag commit' + at)}")
            print(f"add commit:                              "
                  f"{stats(timed(lambda: reg.add(next(more)), 10), 'add commit' + at)}")
            if not label:
                t = time.perf_counter()
                reg.compact()
                secs = RUN.record(f"compact(), {args.rows} scenes", "seconds", time.perf_counter() - t, "s")
                print(f"compact(): {secs:.1f} s")
        sustained(root, args.sustained, RegistryConfig)
        t = time.perf_counter()
        problems = reg.verify()
        RUN.record_all(f"verify, {args.rows} scenes",
                       {"seconds": time.perf_counter() - t, "blobs": len(reg.referenced()),
                                                       "problems": len(problems)}, {"seconds": "s"})
        print(f"verify ({len(reg.referenced())} blobs): {time.perf_counter() - t:.2f} s, problems: {len(problems)}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
