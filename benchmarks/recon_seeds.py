"""Benchmark: the recon stage alone on a finished PosedClip at several seeds (quality and its spread).

A change to the training loop moves its floating-point order, and with it the run: one seed's
PSNR says little (seed spreads of 0.2-1.0 dB on the GoPro clip and the demo street). This runs
the stage's `build` (prior, training, held-out evaluation) once per `ReconConfig.seed`, one
after the other, and prints held-out PSNR / SSIM, Gaussians and training seconds per seed with
the mean and spread. POSED is a factory work folder's `metric` stage (the PosedClip the recon
stage reads), e.g. `vid2sim-work/clips/<clip>/metric`.

    .venv/bin/python benchmarks/recon_seeds.py POSED [--seeds 0 1 2] [--preset fast] [--threads 2]
        [--set FIELD=VALUE ...] [--label NAME] [--keep DIR]

`--set` replaces `ReconConfig` fields of the preset, top-level or nested by a dotted name (a schedule
variant, e.g. `--set coarse_iterations=1000 --set coarse_scale=0.5`, `--set densify.stop_iter=1200`);
values parse as the field's type (`vid2sim ingest --set`'s rules).
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import tempfile
from pathlib import Path
from typing import Iterator

from common import Run, add_run_args
from vid2sim.cli.settings import apply_overrides
from vid2sim.factory.recon import trainer
from vid2sim.factory.recon.config import preset
from vid2sim.threads import set_thread_pools

METRICS = {"psnr": "dB", "ssim": "", "n_gaussians": "", "train_seconds": "s", "train_cpu_seconds": "s"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("posed", type=Path, help="a PosedClip folder (a work folder's metric stage)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="FIELD=VALUE",
                    help="replace a ReconConfig field of the preset, nested ones by a dotted name (repeatable)")
    ap.add_argument("--label", default=None, help="case name (default: the PosedClip folder)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep each seed's reconstruction in KEEP/seed-N (default: a temporary folder)")
    add_run_args(ap)
    a = ap.parse_args()
    if not (a.posed / "cameras.parquet").is_file():
        raise SystemExit(f"{a.posed}: not a PosedClip folder (cameras.parquet missing)")
    config(a, 0)  # unknown fields or presets fail before any work
    set_thread_pools(a.threads)
    with Run("recon_seeds", a) as run:
        measure(run, a)


def config(a: argparse.Namespace, seed: int):
    """The preset with the `--set` fields (dotted names reach nested configs) and the seed."""
    try:
        return apply_overrides(preset(a.preset, seed=seed), a.overrides)
    except ValueError as e:  # SettingError, RangeError: the field and the reason
        raise SystemExit(f"--preset {a.preset}: {e}") from None


@contextlib.contextmanager
def output_folder(keep: Path | None, seed: int) -> Iterator[Path]:
    """KEEP/seed-N (created, kept) or a temporary folder removed afterwards."""
    if keep is None:
        with tempfile.TemporaryDirectory(prefix="recon-seed-") as out:
            yield Path(out)
    else:
        (keep / f"seed-{seed}").mkdir(parents=True, exist_ok=True)
        yield keep / f"seed-{seed}"


def measure(run: Run, a: argparse.Namespace) -> None:
    label = a.label or str(a.posed)
    psnrs = []
    for seed in a.seeds:
        conf = config(a, seed)
        with output_folder(a.keep, seed) as out:
            summary = trainer.build(conf, a.posed, out, f"seed-{seed}")
        values = {k: summary[k] for k in METRICS}
        run.record_all(f"{label}, seed {seed}", values, METRICS,
                       {"preset": a.preset, "threads": a.threads, "seed": seed})
        psnrs.append(values["psnr"])
        print(f"seed {seed}: PSNR {values['psnr']:.2f} dB, SSIM {values['ssim']:.3f}, "
              f"{values['n_gaussians']} Gaussians, training {values['train_seconds']:.1f} s "
              f"({values['train_cpu_seconds']:.1f} CPU-s)", flush=True)
    mean = statistics.fmean(psnrs)
    spread = max(psnrs) - min(psnrs)
    run.record_all(f"{label}, {len(psnrs)} seeds", {"psnr_mean": mean, "psnr_spread": spread}, "dB",
                   {"preset": a.preset, "threads": a.threads, "seeds": list(a.seeds), "set": a.overrides})
    print(f"{len(psnrs)} seeds: PSNR mean {mean:.2f} dB, spread {spread:.2f} dB")


if __name__ == "__main__":
    main()
