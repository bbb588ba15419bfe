"""Pipeline benchmark: end-to-end ingest timings on an embedded local Ray runtime.

    .venv/bin/python benchmarks/pipeline.py gopro       # 10 s GoPro clip -> registered scene (fast preset)
    .venv/bin/python benchmarks/pipeline.py parallel    # 4 synthetic clips: 2 workers vs one after another
    .venv/bin/python benchmarks/pipeline.py speed       # recon presets side by side: demo street and GoPro clip

`gopro` reads ../shared/data (skips with a message when absent). `speed` ingests the demo street
(generated, with ground truth) and the GoPro clip (when present) once with each reconstruction
preset (`--before fast --after quick` by default, everything else equal; `--after none` runs the
`before` column alone, e.g. to compare two commits; `--before-set` / `--after-set FIELD=VALUE` change
a column's recon preset, e.g. `--after fast --after-set iterations=1500`, or another stage's config
by its section, e.g. `--after-set sfm.tracks_per_view=200`) and prints per-stage
wall seconds, the recon stage's process CPU seconds and the quality figures side by side: held-out
PSNR / SSIM, the walked corridor (path on walkable, pieces, corridor area) and, on the demo
street, walkable IoU and collision-mesh accuracy / completeness against ground truth. `parallel` compares
ingesting N clips in one call (clips share the CPUs: each clip's tasks get CPUs/N, so two
clips run at once on 2 cores) against N calls of one clip each (each clip gets every CPU).
Each run uses a fresh work folder and registry, so nothing is cached between runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from common import Run, add_run_args  # noqa: E402  (benchmarks/common.py)
from vid2sim.factory.runtime.pipeline import ingest, preset  # noqa: E402

DATA = Path(os.environ.get("VID2SIM_SHARED_DATA", ROOT.parent / "shared" / "data"))


def run_ingest(inputs: list[str], work: Path, **kw) -> tuple[float, dict]:
    t0 = time.perf_counter()
    report = ingest(inputs, str(work / "registry"), workdir=work / "clips", conf=preset("fast"), num_cpus=2, **kw)
    seconds = time.perf_counter() - t0
    return seconds, report.to_json()


def bench_gopro(run: Run, args: argparse.Namespace) -> None:
    video = DATA / "gopro_max_sidewalk" / "max-heromode.mp4"
    if not video.is_file():
        run.skip("gopro", f"{video} is absent (benchmarks read ../shared/data beside the project)")
        return
    work = Path(tempfile.mkdtemp(prefix="bench-gopro-"))
    seconds, rep = run_ingest([str(video)], work, licence="Apache-2.0 OR MIT", capture_height=1.5)
    clip = rep["clips"][0]
    case = "gopro 10.5 s 848x480, fast preset"
    run.record_all(case, {"ok": clip["ok"], "reason": clip["reason"]})
    run.record_all(case, {f"{k} s": v for k, v in clip["stage_seconds"].items()}, "s")
    print(json.dumps({"clip": clip["clip"], "ok": clip["ok"], "reason": clip["reason"],
                      "stage_seconds": clip["stage_seconds"]}, indent=2))
    if clip["ok"]:
        from vid2sim.registry import Registry

        rec = Registry(str(work / "registry")).show(clip["scene_id"])
        keys = ("recon.psnr", "recon.ssim", "sfm.registered_fraction", "sfm.mean_reproj_error_px",
                "recon.n_gaussians", "walkable.walkable_area_m2", "meshing.collision_faces")
        run.record_all(case, {k: rec.metrics.get(k) for k in keys},
                       {"walkable.walkable_area_m2": "m2", "sfm.mean_reproj_error_px": "px", "recon.psnr": "dB"})
        print({k: rec.metrics.get(k) for k in keys})
    corridor = next(work.glob("clips/*/walkable/corridor.json"), None)  # written even when gated
    if corridor is not None:
        c = json.loads(corridor.read_text())
        run.record_all(case, {"corridor walkable_fraction": c["walkable_fraction"],
                              "corridor path_components": c["path_components"],
                              "corridor_area_m2": c["corridor_area_m2"], "corridor gate passed": c["passed"]},
                       {"corridor_area_m2": "m2"})
        print(f"corridor: {c['walkable_fraction']:.1%} of the walked path walkable (target >= 99 %), "
              f"{c['path_components']} component(s) (target 1), {c['corridor_area_m2']:.3f} m^2 of "
              f"collision surface in the body corridor (target < 0.05); gate "
              f"{'passed' if c['passed'] else 'failed: ' + c['reasons']}")
    run.record(case, "wall_s (target <= 1200)", seconds, "s")
    print(f"gopro 10.5 s 848x480 -> registered scene: {seconds:.0f} s wall (target <= 1200 s)")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


def synthetic_clips(n: int, seconds: float, root: Path) -> list[str]:
    from vid2sim.factory.synthetic.config import preset as street_preset
    from vid2sim.factory.synthetic.make_street import main as make_street

    out = []
    for seed in range(n):
        conf = street_preset("demo", seed=seed, duration_s=seconds, width=640, height=360)
        out.append(str(make_street(conf, root / f"street-{seed}") / "video.mp4"))
    return out


def bench_parallel(run: Run, args: argparse.Namespace) -> None:
    root = Path(tempfile.mkdtemp(prefix="bench-parallel-"))
    videos = synthetic_clips(args.clips, args.seconds, root / "videos")
    seq = 0.0
    for i, v in enumerate(videos):
        s, rep = run_ingest([v], root / f"seq-{i}", licence="CC0", capture_height=1.5)
        seq += s
        run.record_all(f"sequential clip {i} of {args.seconds:g} s", {"wall_s": s, "ok": rep["clips"][0]["ok"]},
                       {"wall_s": "s"}, {"clips": args.clips})
        print(f"sequential clip {i}: {s:.0f} s ok={rep['clips'][0]['ok']} {rep['clips'][0]['reason'] or ''}")
    par, rep = run_ingest(videos, root / "par", licence="CC0", capture_height=1.5)
    ok = sum(c["ok"] for c in rep["clips"])
    run.record_all(f"{args.clips} clips of {args.seconds:g} s",
                   {"one after another s": seq, "in one ingest s": par, "ok": ok,
                    "ratio (target <= 0.60)": par / seq}, {"one after another s": "s", "in one ingest s": "s"})
    print(f"{args.clips} clips of {args.seconds:.0f} s: one after another {seq:.0f} s; "
          f"in one ingest (2 at a time) {par:.0f} s ({ok}/{args.clips} ok); ratio {par / seq:.2f} (target <= 0.60)")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)


def column_config(recon: str, sets: list[str]):
    """The `fast` pipeline with recon preset `recon` and the column's `sets` ('field=value'): a dotted
    name that starts with a pipeline section reaches that stage's config (sfm.tracks_per_view=200),
    any other name is a recon field (iterations=1500, densify.stop_iter=1000). A bad name or value
    raises ValueError naming the field and the reason."""
    from dataclasses import fields, replace

    from vid2sim.cli.settings import apply_overrides
    from vid2sim.factory.recon.config import preset as recon_preset
    from vid2sim.factory.runtime.config import PipelineConfig

    sections = {f.name for f in fields(PipelineConfig)}
    scoped = [s if s.split("=", 1)[0].split(".", 1)[0] in sections else f"recon.{s}" for s in sets]
    return apply_overrides(replace(preset("fast"), recon=recon_preset(recon)), scoped)


def column_label(recon: str, sets: list[str]) -> str:
    """A column's recon preset and its settings, e.g. 'fast iterations=1500'."""
    return " ".join([recon, *sets])


def ingest_with(video: str, work: Path, recon: str, sets: list[str], **kw):
    """One clip through the pipeline with `column_config(recon, sets)`: (wall s, ClipResult, registry)."""
    conf = column_config(recon, sets)
    t0 = time.perf_counter()
    report = ingest([video], str(work / "registry"), workdir=work / "clips", conf=conf, num_cpus=2, **kw)
    return time.perf_counter() - t0, report.results[0], str(work / "registry")


def clip_figures(result, registry: str, synth_dir: Path | None) -> dict:
    """Stage seconds, recon CPU seconds and the quality figures of one finished clip."""
    from vid2sim.factory.runtime.pipeline import bundle_path
    from vid2sim.factory.runtime.runner import local_outputs

    fig = {f"{k} s": v for k, v in result.seconds.items()}
    if not result.ok:
        return {**fig, "failed": f"{result.failed_stage}: {result.reason}"}
    rm = json.loads((local_outputs(result.work, "recon").dir / "metrics.json").read_text())
    fig.update({"recon CPU s": rm.get("cpu_seconds"), "recon prior CPU s": rm.get("prior_cpu_seconds"),
                "recon train CPU s": rm.get("train_cpu_seconds"), "recon iterations": rm.get("iterations"),
                "splats": rm.get("n_gaussians"), "held-out PSNR dB": rm.get("psnr"),
                "held-out SSIM": rm.get("ssim")})
    scene_dir = bundle_path(result.work)
    metrics = json.loads((scene_dir / "scene.json").read_text())["metrics"]
    for k in ("corridor.walkable_fraction", "corridor.path_components", "corridor.corridor_area_m2"):
        fig[k] = metrics.get(k)
    if synth_dir is not None:
        import trimesh

        from vid2sim.factory.evaluation.synthetic_gt import scene_errors
        from vid2sim.factory.sfm.posed import PosedClip
        from vid2sim.formats.walkable import load_walkable

        gt = scene_errors(PosedClip.load(local_outputs(result.work, "metric").dir), synth_dir,
                          trimesh.load(scene_dir / "collision.ply", force="mesh"),
                          load_walkable(scene_dir / "walkable.npz"))
        fig.update({"walkable IoU (GT)": gt["walkable_iou"],
                    "collision accuracy median m (GT)": gt["collision_accuracy_median_m"],
                    "near-path accuracy median m (GT)": gt.get("near_path_accuracy_median_m"),
                    "near-path completeness (GT)": gt.get("near_path_completeness")})
    return fig


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def bench_speed(run: Run, args: argparse.Namespace) -> None:
    import platform

    print(f"host: {platform.node()} {os.cpu_count()} CPUs, ingest with num_cpus=2; loadavg at start "
          f"{os.getloadavg()} (wall seconds on a shared machine include other processes' load; the recon "
          f"CPU seconds are process time)")
    clips = []
    root = Path(tempfile.mkdtemp(prefix="bench-speed-"))
    from vid2sim.factory.synthetic.config import preset as street_preset
    from vid2sim.factory.synthetic.make_street import main as make_street

    street = street_preset("demo", seed=0)
    synth = make_street(street, root / "synthetic")
    clips.append(("demo street", str(synth / "video.mp4"), synth,
                  dict(licence="CC0-synthetic", capture_height=street.capture_height)))
    video = DATA / "gopro_max_sidewalk" / "max-heromode.mp4"
    if video.is_file():
        clips.append(("gopro", str(video), None, dict(licence="Apache-2.0 OR MIT", capture_height=1.5)))
    else:
        run.skip("gopro", f"{video} is absent (benchmarks read ../shared/data beside the project)")
    for name, path, synth_dir, kw in clips:
        cols = {}
        columns = [("before", args.before, args.before_set)]
        columns += [("after", args.after, args.after_set)] if args.after != "none" else []
        for label, recon, sets in columns:
            work = root / f"{name.replace(' ', '-')}-{label}"
            wall, result, registry = ingest_with(path, work, recon, sets, **kw)
            recon = column_label(recon, sets)
            cols[label] = {"recon preset": recon, "video to registered scene s": wall,
                           **clip_figures(result, registry, synth_dir)}
            run.record_all(f"{name}: {label} ({recon})", {k: v for k, v in cols[label].items()
                                                          if isinstance(v, (int, float))})
        cols.setdefault("after", {})
        keys = list(dict.fromkeys([*cols["before"], *cols["after"]]))
        versus = f" vs {column_label(args.after, args.after_set)} (after)" if args.after != "none" else ""
        print(f"\n## {name}: recon preset {column_label(args.before, args.before_set)} (before){versus}")
        print(f"{'figure':<36}{'before':>14}{'after':>14}")
        for k in keys:
            print(f"{k:<36}{_fmt(cols['before'].get(k)):>14}{_fmt(cols['after'].get(k)):>14}")
        for k in ("recon s", "recon CPU s", "video to registered scene s"):
            b, a = cols["before"].get(k), cols["after"].get(k)
            if b and a:
                print(f"{k}: speed-up x{b / a:.2f}")
    print(f"\nloadavg at end {os.getloadavg()}")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=["gopro", "parallel", "speed"])
    ap.add_argument("--before", default="fast", help="speed: the recon preset of the 'before' column")
    ap.add_argument("--after", default="quick",
                    help="speed: the recon preset of the 'after' column ('none': the 'before' column alone)")
    for side in ("before", "after"):
        ap.add_argument(f"--{side}-set", action="append", default=[], metavar="FIELD=VALUE",
                        help=f"speed: replace a field of the '{side}' column's recon preset, nested ones by a "
                             f"dotted name (e.g. densify.stop_iter=1000), or of another stage by its section "
                             f"(e.g. sfm.tracks_per_view=200; repeatable)")
    ap.add_argument("--clips", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--keep", action="store_true", help="keep the work folders")
    add_run_args(ap)
    args = ap.parse_args()
    if args.what == "speed":  # a bad preset or setting fails before any ingest
        for side, recon, sets in (("before", args.before, args.before_set), ("after", args.after, args.after_set)):
            try:
                if recon != "none":
                    column_config(recon, sets)
            except ValueError as e:
                raise SystemExit(f"--{side} {recon}: {e}") from None
    with Run("pipeline", args) as run:
        {"gopro": bench_gopro, "parallel": bench_parallel, "speed": bench_speed}[args.what](run, args)


if __name__ == "__main__":
    main()
