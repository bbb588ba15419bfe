"""Loopback cluster: N synthetic street clips, video to registry commit, on 1 Ray node against 2.

    .venv/bin/python benchmarks/cluster.py --clips 4

Renders N synthetic street clips (seeds 1..N, 2 s, 320x180, 30 fps, H.264), then for each node
count starts moto's S3 server and a Ray cluster on 127.0.0.1 (1 CPU per node, own temp and
scratch dirs, token auth) and, from a separate driver process, uploads the videos to the store
and runs the WHOLE chain of every clip on the cluster: decode (each node fetches its clip's
video from the store), masks, SfM, metric, recon, meshing, walkable, bundle, then commits each
bundle to the registry on S3. The work folder is on S3 too: every stage fetches the folders it
reads into its node's scratch and uploads its own. Settings are the `fast` pipeline preset
except a 60-iteration reconstruction and an opened corridor gate: this measures distribution
and its costs, not scene quality (a 60-iteration scene does not pass the gate).

Printed per node count: wall seconds (first submit to last commit), the ratio 2 nodes / 1 node,
and where the time goes, in seconds summed over clips: compute (each stage's own seconds, from
its stage.json marker), object-store transfers (sync_down / sync_up / source fetch inside the
stage tasks, as `staging.transfer_totals` counts them), other in-task time (task wall minus
both: imports, inputs, thread setup), the driver's commits (bundle fetch + registry add), idle
CPU slots (nodes x 1 CPU x wall minus the busy task seconds) and the clips' waits (from a clip's
first submit to its commit, minus its task and commit seconds: queueing and Ray scheduling).
Then per-stage compute and transfer seconds, and the worker processes' CPU seconds.

What it can show: every stage runs through the object store on either node, what the store
round trips cost next to the compute, and how much slot time is idle. What it cannot: a speed-up
from more hardware. Both "nodes" share this machine's cores (2 on the reference machine), so
two 1-CPU nodes give at most the machine's second core; wall seconds also count whatever else
runs on the machine, while the CPU seconds are the workers' own. Then a paper estimate for
1,000 ten-second clips on a named cloud instance from the per-stage times of the GoPro clip,
fast preset (docs/results.md).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from common import Run, add_run_args  # noqa: E402  (benchmarks/common.py)

# Measured per 10.5 s GoPro clip, fast preset at 160 px, 2 vCPUs (benchmarks/pipeline.py gopro).
STAGE_SECONDS = {"decode": 12, "masks": 4, "sfm": 59, "metric": 0.7, "recon": 132, "meshing": 16}
INSTANCE = ("c6i.4xlarge", 16, 0.68)  # name, vCPUs, on-demand USD/hour (us-east-1)
TRANSFER_KINDS = ("down", "up", "source")


def render_clips(clips: int, seconds: float, width: int, height: int, root: Path) -> list[str]:
    """Synthetic street videos (seeds 1..clips); returns their paths."""
    from vid2sim.factory.synthetic.config import preset as street_preset
    from vid2sim.factory.synthetic.make_street import main as make_street

    out = []
    for seed in range(1, clips + 1):
        conf = street_preset("test", seed=seed, duration_s=seconds, width=width, height=height, write_depth=False)
        out.append(str(make_street(conf, root / f"street{seed}") / "video.mp4"))
    return out


def pipeline_conf(width: int, iterations: int):
    """The `fast` preset with a short reconstruction and the corridor gate opened (see doc)."""
    from dataclasses import replace

    from vid2sim.factory.evaluation.corridor import CorridorConfig
    from vid2sim.factory.recon.config import preset as recon_preset
    from vid2sim.factory.runtime.pipeline import preset

    conf = preset("fast")
    recon = recon_preset("fast", iterations=iterations, max_width=width, checkpoint_every=1000)
    recon.densify = replace(recon.densify, start_iter=20, stop_iter=max(30, iterations - 10), every=10)
    recon.loss = replace(recon.loss, geometry_from_iter=20)
    return replace(conf, recon=recon, corridor=CorridorConfig(
        gate_min_walkable_fraction=0.0, gate_max_components=1000, gate_max_area_m2=1e9)).resolved()


def drive(cfg: dict, out: Path) -> None:
    """Driver process: upload the videos, run every clip's whole chain on the cluster, commit."""
    import ray

    from vid2sim.factory.runtime.object_store import ObjectStore
    from vid2sim.factory.runtime.orchestrator import run_clips
    from vid2sim.factory.runtime.pipeline import (STEP_NAMES, bundle_path, clip_work, plan_jobs,
                                                  rows_from_inputs, stage_specs)
    from vid2sim.factory.runtime.stage_cache import StageError
    from vid2sim.factory.runtime.staging import transfer_totals
    from vid2sim.registry import Registry

    sources, store, registry = ObjectStore(cfg["sources"]), ObjectStore(cfg["work"]), Registry(cfg["registry"])
    uris = []
    for i, video in enumerate(cfg["videos"], 1):
        sources.write_bytes(f"clip{i}.mp4", Path(video).read_bytes())
        uris.append(f"{sources.root}/clip{i}.mp4")
    conf = pipeline_conf(cfg["width"], cfg["iterations"])
    cache = out.parent / f"driver-cache-{out.stem}"
    jobs, failed = plan_jobs(rows_from_inputs(uris, "CC0", cfg["capture_height"]), conf, cache)
    if failed:
        raise RuntimeError(f"sources failed: {[f.reason for f in failed]}")
    shutil.rmtree(cache)  # no shared disk: each clip's decode fetches its video from the store
    clips = [(j.spec.clip_id, clip_work(j, conf, store.root, 1.0)) for j in jobs]
    ray.init(address=cfg["address"], log_to_driver=False)
    first: dict[str, float] = {}
    ended: dict[str, float] = {}
    commits: dict[str, dict] = {}

    def on_update(state) -> None:
        now = time.perf_counter() - t0
        first.setdefault(state.clip_id, now)
        if state.status in ("done", "failed"):
            ended[state.clip_id] = now

    def commit(state) -> None:
        c0, m0 = time.perf_counter(), transfer_totals()["down_s"]
        try:
            rec = registry.add(bundle_path(state.work))
        except Exception as e:  # as ingest does: the clip fails, the others go on
            raise StageError("commit", "commit_failed", str(e)) from e
        commits[state.clip_id] = {"s": time.perf_counter() - c0, "fetch_s": transfer_totals()["down_s"] - m0,
                                  "version": rec.version}

    t0 = time.perf_counter()
    results = run_clips(clips, stage_specs(1.0), on_update=on_update, on_clip_done=commit)
    wall = time.perf_counter() - t0
    ray.shutdown()
    report = {"wall_s": wall, "ok": sum(r.ok for r in results), "clips": []}
    for r in results:
        markers = {s: json.loads(m) for s in STEP_NAMES if (m := store.marker(f"{r.clip_id}/{s}"))}
        report["clips"].append({
            "clip": r.clip_id, "ok": r.ok, "failed": f"{r.failed_stage}: {r.reason}: {r.detail}"[:2000],
            "task_s": r.seconds, "compute_s": {s: markers[s]["seconds"] for s in r.seconds if s in markers},
            "stats": r.stats, "commit": commits.get(r.clip_id),
            "span_s": ended.get(r.clip_id, wall) - first.get(r.clip_id, 0.0)})
    report["nodes"] = len({st["node"] for c in report["clips"] for st in c["stats"].values() if st.get("node")})
    report["registry_scenes"] = len(registry.list())
    report["registry_problems"] = registry.verify()  # the log continuity check runs on S3 too
    out.write_text(json.dumps(report))


def measure(nodes: int, cfg: dict, tmp: Path) -> dict:
    """Fresh S3 server and `nodes`-node cluster; the driver's report plus the cluster start time."""
    from cluster_fixtures import ray_cluster, s3_server

    t0 = time.perf_counter()
    with s3_server() as s3, ray_cluster(workers=nodes - 1, extra_env=s3.env) as cluster:
        started = time.perf_counter() - t0
        out = tmp / f"report-{nodes}.json"
        conf = {**cfg, "address": cluster.address, "sources": s3.uri("sources"), "work": s3.uri("work"),
                "registry": s3.uri("registry")}
        (tmp / f"drive-{nodes}.json").write_text(json.dumps(conf))
        subprocess.run([sys.executable, __file__, "--drive", str(tmp / f"drive-{nodes}.json"), str(out)],
                       env=cluster.env, check=True)
        return {**json.loads(out.read_text()), "cluster_start_s": started}


def breakdown(r: dict, nodes: int) -> dict:
    """Where the time went, seconds summed over clips (see the module doc)."""
    clips = r["clips"]
    task = sum(sum(c["task_s"].values()) for c in clips)
    compute = sum(sum(c["compute_s"].values()) for c in clips)
    moved = {k: sum(st.get(f"{k}_s", 0.0) for c in clips for st in c["stats"].values()) for k in TRANSFER_KINDS}
    transfer = sum(moved.values())
    commit = sum(c["commit"]["s"] for c in clips if c["commit"])
    return {"wall_s": r["wall_s"], "committed": r["ok"], "nodes used": r["nodes"],
            "compute_s": compute, "transfer_s": transfer, **{f"transfer {k} s": v for k, v in moved.items()},
            "other in-task s": task - compute - transfer, "commit s": commit,
            "commit fetch s": sum(c["commit"]["fetch_s"] for c in clips if c["commit"]),
            "idle CPU-slot s": nodes * r["wall_s"] - task,
            "clip waits s": sum(c["span_s"] - sum(c["task_s"].values()) - (c["commit"] or {}).get("s", 0.0)
                                for c in clips),
            "task s": task, "worker CPU s": sum(st.get("cpu_s", 0.0) for c in clips for st in c["stats"].values()),
            "MB down": sum(st.get("down_bytes", 0) for c in clips for st in c["stats"].values()) / 1e6,
            "MB up": sum(st.get("up_bytes", 0) for c in clips for st in c["stats"].values()) / 1e6,
            "cluster start s": r["cluster_start_s"]}


def per_stage(r: dict) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for c in r["clips"]:
        for stage, task_s in c["task_s"].items():
            st = c["stats"].get(stage, {})
            row = out.setdefault(stage, {"compute_s": 0.0, "transfer_s": 0.0, "task_s": 0.0, "worker CPU s": 0.0})
            row["compute_s"] += c["compute_s"].get(stage, 0.0)
            row["transfer_s"] += sum(st.get(f"{k}_s", 0.0) for k in TRANSFER_KINDS)
            row["task_s"] += task_s
            row["worker CPU s"] += st.get("cpu_s", 0.0)
    return out


def estimate_figures(clips: int = 1000) -> dict:
    """The paper estimate's figures (paper_estimate)."""
    name, vcpus, price = INSTANCE
    per_clip = sum(STAGE_SECONDS.values()) * 10 / 10.5  # s on 2 vCPUs, scaled to 10 s of video
    vcpu_hours = per_clip * 2 * clips / 3600
    instance_hours = vcpu_hours / vcpus
    return {"clips": clips, "seconds per clip on 2 vCPUs": per_clip, "vCPU-hours": vcpu_hours,
            f"{name} instance-hours": instance_hours, "on-demand USD": instance_hours * price,
            "wall min with 20 workers": instance_hours / 20 * 60,
            "clips per hour (20 workers)": 8 * 20 * 3600 / per_clip}


def paper_estimate(clips: int = 1000) -> str:
    """Throughput and cost of `clips` ten-second clips from the measured 2-vCPU stage times."""
    name, _, price = INSTANCE
    f = estimate_figures(clips)
    per_clip, vcpu_hours = f["seconds per clip on 2 vCPUs"], f["vCPU-hours"]
    instance_hours = f[f"{name} instance-hours"]
    return (f"paper estimate: {clips} x 10 s clips, fast preset: {per_clip:.0f} s per clip on 2 vCPUs "
            f"-> {vcpu_hours:.0f} vCPU-hours -> {instance_hours:.1f} {name} instance-hours "
            f"(~${instance_hours * price:.0f} on demand at ${price}/h); with 20 workers "
            f"{instance_hours / 20 * 60:.0f} min wall, {8 * 20 * 3600 / per_clip:.0f} clips/hour "
            f"(8 clips of 2 vCPUs per instance). Assumes stages scale like on this machine and "
            f"S3 transfers are small next to SfM + recon.")


def print_tables(res: dict[int, dict], clips: int) -> None:
    b = {n: breakdown(r, n) for n, r in res.items()}
    ratio = b[2]["wall_s"] / b[1]["wall_s"] if 1 in b and 2 in b else float("nan")
    cols = ("compute_s", "transfer_s", "other in-task s", "commit s", "idle CPU-slot s", "clip waits s")
    print(f"\n{'nodes':>5} {'used':>4} {'clips':>5} {'ok':>3} {'wall s':>7} {'ratio':>6} | " +
          " ".join(f"{c.replace('_s', ' s'):>15}" for c in cols) + f" | {'worker CPU s':>12}")
    for n, row in b.items():
        print(f"{n:>5} {row['nodes used']:>4} {clips:>5} {row['committed']:>3} {row['wall_s']:>7.1f} "
              f"{(ratio if n == 2 else 1.0):>6.2f} | " + " ".join(f"{row[c]:>15.1f}" for c in cols) +
              f" | {row['worker CPU s']:>12.1f}")
    print("(seconds summed over clips; transfers = store -> scratch, scratch -> store and video fetch "
          "inside the stage tasks; both nodes share this machine's cores)")
    stages = {n: per_stage(r) for n, r in res.items()}
    names = list(dict.fromkeys(s for st in stages.values() for s in st))
    print(f"\n{'stage':<9}" + "".join(f"{f'{n}n compute':>12}{f'{n}n transfer':>13}{f'{n}n CPU':>9}" for n in stages))
    for s in names:
        print(f"{s:<9}" + "".join(f"{stages[n].get(s, {}).get('compute_s', 0):>12.1f}"
                                  f"{stages[n].get(s, {}).get('transfer_s', 0):>13.2f}"
                                  f"{stages[n].get(s, {}).get('worker CPU s', 0):>9.1f}" for n in stages))
    for n, row in b.items():
        print(f"{n} node(s): {row['MB down']:.1f} MB down, {row['MB up']:.1f} MB up; transfers down "
              f"{row['transfer down s']:.1f} s, up {row['transfer up s']:.1f} s, video fetch "
              f"{row['transfer source s']:.1f} s; commits fetched bundles in {row['commit fetch s']:.1f} s; "
              f"cluster start {row['cluster start s']:.0f} s (not in wall)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", type=int, default=4)
    p.add_argument("--seconds", type=float, default=2.0, help="length of each synthetic clip")
    p.add_argument("--width", type=int, default=320, help="video width (height = width * 9 / 16)")
    p.add_argument("--iterations", type=int, default=60, help="reconstruction iterations")
    p.add_argument("--nodes", type=int, nargs="+", default=[1, 2], help="node counts to measure")
    p.add_argument("--drive", nargs=2, metavar=("CONFIG", "OUT"), help=argparse.SUPPRESS)
    add_run_args(p)
    args = p.parse_args()
    if args.drive:
        drive(json.loads(Path(args.drive[0]).read_text()), Path(args.drive[1]))
        return
    import tempfile

    height = args.width * 9 // 16
    cfg = {"width": args.width, "iterations": args.iterations, "capture_height": 1.5}
    with Run("cluster", args, config={"stage_seconds": STAGE_SECONDS, "instance": INSTANCE,
                                      "clip": f"synthetic street, {args.seconds:g} s, {args.width}x{height}, 30 fps",
                                      "recon iterations": args.iterations, "CPUs per node": 1}) as run:
        with tempfile.TemporaryDirectory(prefix="v2sbench-") as tmp:
            t0 = time.perf_counter()
            cfg["videos"] = render_clips(args.clips, args.seconds, args.width, height, Path(tmp) / "videos")
            print(f"rendered {args.clips} clips of {args.seconds:g} s at {args.width}x{height} in "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)
            res = {}
            for n in args.nodes:
                res[n] = measure(n, cfg, Path(tmp))
                print(f"{n} node(s): {res[n]['ok']}/{args.clips} committed in {res[n]['wall_s']:.1f} s", flush=True)
        for n, r in res.items():
            case = f"{n} node(s), 1 CPU each, {args.clips} clips, whole chain"
            row = breakdown(r, n)
            run.record_all(case, row, {k: ("MB" if k.startswith("MB") else "" if k in ("committed", "nodes used")
                                           else "s") for k in row})
            run.record(case, "registry problems", len(r["registry_problems"]))
            for stage, st in per_stage(r).items():
                run.record_all(f"{n} node(s), {args.clips} clips, stage {stage}", st, "s")
            for c in r["clips"]:
                if not c["ok"]:
                    run.note(f"{n} node(s): clip {c['clip']} failed: {c['failed'][:300]}")
        if 1 in res and 2 in res:
            run.record(f"ratio 2 nodes / 1 node, {args.clips} clips, whole chain", "wall ratio",
                       res[2]["wall_s"] / res[1]["wall_s"])
        print_tables(res, args.clips)
        est = estimate_figures()
        run.record_all("paper estimate, 1000 x 10 s clips, fast preset", est,
                       {"seconds per clip on 2 vCPUs": "s", "vCPU-hours": "h", f"{INSTANCE[0]} instance-hours": "h",
                        "on-demand USD": "USD", "wall min with 20 workers": "min"})
        print(paper_estimate())


if __name__ == "__main__":
    main()
