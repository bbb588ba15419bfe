"""Loopback cluster fan-out: N clips over 1 Ray node against 2 nodes, registry and work on S3.

    .venv/bin/python benchmarks/cluster.py --clips 4

Starts moto's S3 server and a Ray cluster on 127.0.0.1 (1 CPU per node, own temp and scratch
dirs, token auth) for each node count, runs the back half (recon -> meshing -> bundle -> commit)
of N synthetic clips from a separate driver process, and prints the wall time of each.
What it can show: the work spreads over nodes through the object store, and the cost of the
store round trips. What it cannot: a speed-up from more hardware, since both "nodes" share this
machine's cores. Then a paper estimate for 1,000 ten-second clips on a named cloud instance from
the per-stage times of the GoPro clip, fast preset (docs/results.md).
"""

from __future__ import annotations

import argparse
import json
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


def drive(address: str, work_uri: str, registry_uri: str, clips: int, out: Path) -> None:
    """Driver process: N clips' back half on the cluster; writes wall time and stage seconds."""
    import ray
    from test_cluster_two_nodes import _clip, _stages

    from vid2sim.factory.runtime.object_store import ObjectStore
    from vid2sim.factory.runtime.orchestrator import run_clips
    from vid2sim.factory.runtime.pipeline import bundle_path
    from vid2sim.registry import Registry

    store, registry = ObjectStore(work_uri), Registry(registry_uri)
    jobs = [_clip(out.parent, store, seed) for seed in range(1, clips + 1)]
    ray.init(address=address, log_to_driver=False)
    t0 = time.perf_counter()
    results = run_clips(jobs, _stages(), on_clip_done=lambda s: registry.add(bundle_path(s.work)))
    wall = time.perf_counter() - t0
    ray.shutdown()
    out.write_text(json.dumps({"wall_s": wall, "ok": sum(r.ok for r in results),
                               "nodes": len({v for r in results for v in r.work.nodes.values()}),
                               "stage_s": [r.seconds for r in results]}))


def measure(workers: int, clips: int, tmp: Path) -> dict:
    from cluster_fixtures import ray_cluster, s3_server

    with s3_server() as s3, ray_cluster(workers=workers, extra_env=s3.env) as cluster:
        out = tmp / f"bench-{workers}.json"
        subprocess.run([sys.executable, __file__, "--drive", cluster.address, s3.uri("work"),
                        s3.uri("registry"), str(clips), str(out)], env=cluster.env, check=True)
        return json.loads(out.read_text())


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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", type=int, default=4)
    p.add_argument("--drive", nargs=5, metavar=("ADDRESS", "WORK", "REGISTRY", "CLIPS", "OUT"))
    add_run_args(p)
    args = p.parse_args()
    if args.drive:
        a = args.drive
        drive(a[0], a[1], a[2], int(a[3]), Path(a[4]))
        return
    import tempfile

    with Run("cluster", args, config={"stage_seconds": STAGE_SECONDS, "instance": INSTANCE}) as run:
        with tempfile.TemporaryDirectory(prefix="v2sbench-") as tmp:
            res = {n: measure(n - 1, args.clips, Path(tmp)) for n in (1, 2)}
        for n, r in res.items():
            run.record_all(f"{n} node(s), 1 CPU each, {args.clips} clips",
                           {"wall_s": r["wall_s"], "committed": r["ok"], "nodes used": r["nodes"]}, {"wall_s": "s"})
            print(f"{n} node(s), 1 CPU each: {args.clips} clips in {r['wall_s']:.1f} s "
                  f"({r['ok']} committed, stages ran on {r['nodes']} node(s))")
        run.record(f"ratio 2 nodes / 1 node, {args.clips} clips", "wall ratio", res[2]["wall_s"] / res[1]["wall_s"])
        print(f"ratio 2 nodes / 1 node: {res[2]['wall_s'] / res[1]['wall_s']:.2f} "
              "(both nodes share this machine's cores: shows spreading, not hardware scaling)")
        est = estimate_figures()
        run.record_all("paper estimate, 1000 x 10 s clips, fast preset", est,
                       {"seconds per clip on 2 vCPUs": "s", "vCPU-hours": "h", f"{INSTANCE[0]} instance-hours": "h",
                        "on-demand USD": "USD", "wall min with 20 workers": "min"})
        print(paper_estimate())


if __name__ == "__main__":
    main()
