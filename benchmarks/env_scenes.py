"""Real factory scenes for the env render benchmark, built once and cached outside the repo.

    .venv/bin/python benchmarks/env_scenes.py [demo] [gopro]   # build (or find) the cached bundles

`demo`: the `make demo` street (synthetic 10 s 854x480 video -> fast-preset ingest).
`gopro`: the shared GoPro MAX sidewalk clip (`../shared/data`, skipped when absent).
The cache root is `$VID2SIM_CACHE/env_render` (default `~/.cache/vid2sim/env_render`); each scene's
bundle folder is `<root>/<name>/clips/<clip>/bundle/scene` (found by its `scene.json`).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Optional

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

DATA = Path(os.environ.get("VID2SIM_SHARED_DATA", ROOT.parent / "shared" / "data"))
CACHE = Path(os.environ.get("VID2SIM_CACHE", Path.home() / ".cache" / "vid2sim")) / "env_render"
GOPRO = DATA / "gopro_max_sidewalk" / "max-heromode.mp4"


def find_bundle(name: str) -> Optional[Path]:
    """The cached bundle folder of scene `name`, or None when it was not built yet."""
    hits = sorted((CACHE / name).glob("clips/**/scene.json"))
    return hits[0].parent if hits else None


def _ingest(name: str, video: str, licence: str, capture_height: float) -> Path:
    from vid2sim.factory.runtime.pipeline import ingest, preset

    work = CACHE / name
    report = ingest([video], str(work / "registry"), workdir=work / "clips", conf=preset("fast"),
                    num_cpus=2, licence=licence, capture_height=capture_height)
    res = report.results[0]
    if not res.ok:
        raise RuntimeError(f"{name}: failed at {res.failed_stage}: {res.reason}")
    return Path(res.context["bundle_dir"])


def build(name: str) -> Optional[Path]:
    """Build scene `name` ('demo' or 'gopro') once; returns its bundle folder (None: no data)."""
    hit = find_bundle(name)
    if hit is not None:
        return hit
    t0 = time.perf_counter()
    if name == "demo":
        from vid2sim.factory.synthetic.config import preset as street_preset
        from vid2sim.factory.synthetic.make_street import main as make_street

        street = street_preset("demo", seed=0)
        video = make_street(street, CACHE / name / "synthetic") / "video.mp4"
        out = _ingest(name, str(video), "CC0-synthetic", street.capture_height)
    elif name == "gopro":
        if not GOPRO.is_file():
            print(f"SKIP gopro: {GOPRO} is absent (../shared/data beside the project)")
            return None
        out = _ingest(name, str(GOPRO), "Apache-2.0 OR MIT", 1.5)
    else:
        raise ValueError(f"unknown scene {name!r} (demo, gopro)")
    print(f"built {name} in {time.perf_counter() - t0:.0f} s: {out}")
    return out


if __name__ == "__main__":
    for n in sys.argv[1:] or ["demo", "gopro"]:
        print(n, build(n))
