"""A real headless browser for the viewer tests: the OS's Chromium driven by Playwright.

Never downloads a browser build: the executable is $VID2SIM_CHROMIUM or the first of
chromium / chromium-browser / google-chrome on PATH (Debian: `apt-get install chromium`).
When no browser can start, `launch_chromium` fails the test with a message saying so.
WebGL runs on SwiftShader (software), so no GPU is needed.
"""

from __future__ import annotations

import os
import shutil
import time
from typing import Callable

import numpy as np
import pytest

CANDIDATES = ("chromium", "chromium-browser", "google-chrome")
ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--no-sandbox"]
VIEWPORT = {"width": 560, "height": 360}


def chromium_path() -> str:
    exe = os.environ.get("VID2SIM_CHROMIUM") or next(filter(None, map(shutil.which, CANDIDATES)), None)
    if not exe:
        pytest.fail("no Chromium for the browser tests: install the OS package (`apt-get install -y chromium`, "
                    "as .ci/run does) or set VID2SIM_CHROMIUM", pytrace=False)
    return exe


def launch_chromium(playwright):
    """A headless Chromium of the OS, or a failed test naming why it cannot start."""
    exe = chromium_path()
    try:
        return playwright.chromium.launch(executable_path=exe, args=ARGS, headless=True)
    except Exception as e:
        pytest.fail(f"Chromium at {exe} cannot start: {e}", pytrace=False)


def sync_playwright():
    try:
        from playwright.sync_api import sync_playwright as start
    except ImportError:
        pytest.fail("playwright is not installed (pip install -e '.[dev]')", pytrace=False)
    return start()


def canvas_pixels(page) -> np.ndarray:
    """RGB [H, W, 3] u8 of the page's 3-D canvas (the largest <canvas>)."""
    import cv2

    canvases = page.locator("canvas")
    boxes = [(canvases.nth(i).bounding_box() or {"width": 0, "height": 0}) for i in range(canvases.count())]
    best = int(np.argmax([b["width"] * b["height"] for b in boxes]))
    png = canvases.nth(best).screenshot(timeout=180_000)
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]


def settled(page, timeout: float = 120.0, ok: Callable[[np.ndarray], bool] = lambda a: True) -> np.ndarray:
    """Canvas pixels once two screenshots in a row agree (and satisfy `ok`), else the last one."""
    end, last = time.monotonic() + timeout, canvas_pixels(page)
    while time.monotonic() < end:
        time.sleep(0.5)
        now = canvas_pixels(page)
        if np.array_equal(now, last) and ok(now):
            return now
        last = now
    return last


def changed_fraction(a: np.ndarray, b: np.ndarray, tol: int = 24) -> float:
    """Fraction of pixels whose colour differs by more than `tol` in any channel."""
    return float((np.abs(a.astype(np.int16) - b.astype(np.int16)).max(axis=2) > tol).mean())


def non_background_fraction(a: np.ndarray, tol: int = 12) -> float:
    """Fraction of pixels that differ from the most common colour (the background)."""
    flat = a.reshape(-1, 3)
    colours, counts = np.unique(flat, axis=0, return_counts=True)
    bg = colours[np.argmax(counts)].astype(np.int16)
    return float((np.abs(flat.astype(np.int16) - bg).max(axis=1) > tol).mean())
