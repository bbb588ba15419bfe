"""Screenshots of `vid2sim view` in the OS's headless Chromium (Playwright, software WebGL).

    .venv/bin/python benchmarks/viewer_shots.py SCENE_OR_BUNDLE --registry ROOT --out docs/viewer_x.png
    .venv/bin/python benchmarks/viewer_shots.py --episode EP.trace.json --out docs/viewer_episode.png --step 40

Starts the viewer on a free port, waits until the canvas stops changing, writes the PNG and
prints the command, the splat count shown and the seconds taken.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import sys
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from vid2sim.viewer.app import open_viewer

ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--no-sandbox"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_still(page, timeout: float = 300.0) -> None:
    """Until two canvas screenshots a second apart agree."""
    last, end = None, time.monotonic() + timeout
    while time.monotonic() < end:
        now = page.locator("canvas").first.screenshot(timeout=300_000)
        if now == last:
            return
        last = now
        time.sleep(1.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?")
    ap.add_argument("--registry")
    ap.add_argument("--episode", type=Path)
    ap.add_argument("--step", type=int, default=0, help="episode step to show")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=760)
    a = ap.parse_args()
    t0 = time.perf_counter()
    viewer = open_viewer(a.scene, registry=a.registry, episode=a.episode, port=free_port())
    if viewer.player is not None:
        viewer.player.slider.value = a.step
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=ARGS)
        page = browser.new_page(viewport={"width": a.width, "height": a.height})
        page.goto(viewer.url)
        page.wait_for_selector("canvas", timeout=300_000)
        time.sleep(3.0)
        page.evaluate("""() => document.querySelectorAll("[class*='Notification-root']").forEach(
            n => { if (n.textContent.includes('Software WebGL')) n.remove(); })""")  # not the scene's
        wait_still(page)
        a.out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(a.out), timeout=300_000)
        browser.close()
    shown = viewer.layers.splats.shown if viewer.layers and viewer.layers.splats else 0
    viewer.stop()
    print(f"command: {' '.join(sys.argv)}")
    print(f"wrote {a.out}: {shown:,} splats shown, {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
