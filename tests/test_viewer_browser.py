"""`vid2sim view` in a real headless Chromium (the OS package, driven by Playwright): the page
loads, the 3-D canvas is not blank, unticking the collision-mesh layer changes the pixels, and
the episode player moves the robot. One GT street scene in a registry and one recorded expert
episode are built once for the module; each test opens its own viewer on a free port."""

from __future__ import annotations

import socket
import time

import gymnasium
import numpy as np
import pytest
from browser import VIEWPORT, changed_fraction, launch_chromium, non_background_fraction, settled, sync_playwright
from street_bundles import street_bundle

import vid2sim.envs  # noqa: F401  (registers the env ids)
from vid2sim.envs.expert import PurePursuitExpert
from vid2sim.envs.recording import record_episodes
from vid2sim.formats.episode_trace import trace_path
from vid2sim.registry import Registry
from vid2sim.viewer.app import open_viewer

SCENE = "synthetic-street-s11"
BUDGET = 5_000  # splats sent to the browser: software WebGL stays quick


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """(registry root, bundle folder, trace file of one recorded expert episode, checkout folder)."""
    root = tmp_path_factory.mktemp("viewer")
    bundle = street_bundle(root, n_splats=5_000)
    reg = Registry(root / "registry")
    reg.add(bundle)
    env = gymnasium.make("vid2sim/PointNav-v0", registry=reg.root, scenes=SCENE, checkout_root=root / "co",
                         training=False)
    video = record_episodes(env, root / "videos", 1, PurePursuitExpert(), seed=3)[0]
    env.close()
    return str(reg.root), bundle, trace_path(video), root / "co"


@pytest.fixture(scope="module")
def browser():
    with sync_playwright() as p:
        b = launch_chromium(p)
        yield b
        b.close()


@pytest.fixture
def page(browser):
    pg = browser.new_page(viewport=VIEWPORT)
    yield pg
    pg.close()


def _open(page, viewer) -> np.ndarray:
    page.goto(viewer.url)
    page.wait_for_selector("canvas", timeout=120_000)
    return settled(page, ok=lambda a: non_background_fraction(a) > 0.05)


def test_scene_page_loads_and_mesh_toggle_changes_pixels(world, page) -> None:
    _, bundle, _, _ = world
    viewer = open_viewer(str(bundle), port=free_port(), budget=BUDGET)
    try:
        before = _open(page, viewer)
        assert non_background_fraction(before) > 0.05, "the 3-D canvas is blank"
        assert page.get_by_text("Scene card").count() and page.get_by_text(SCENE).count()
        page.get_by_label("collision mesh").click()  # untick the layer in the browser
        deadline = time.monotonic() + 30
        while viewer.scene.toggles["collision mesh"].value and time.monotonic() < deadline:
            time.sleep(0.1)
        assert viewer.scene.toggles["collision mesh"].value is False
        after = settled(page, ok=lambda a: changed_fraction(before, a) > 0.01)
        assert changed_fraction(before, after) > 0.01, "hiding the collision mesh did not change the picture"
    finally:
        viewer.stop()


def test_episode_player_moves_the_robot(world, page) -> None:
    registry, _, trace, checkouts = world
    viewer = open_viewer(episode=trace, registry=registry, port=free_port(), budget=BUDGET, checkouts=checkouts)
    try:
        start = _open(page, viewer)
        robot0 = np.array(viewer.player.robot.position)
        page.get_by_role("button", name="Play").click()
        deadline = time.monotonic() + 60
        while viewer.player.slider.value < 10 and time.monotonic() < deadline:
            time.sleep(0.1)
        page.get_by_role("button", name="Pause").click()
        assert viewer.player.slider.value >= 10, "the player did not advance"
        assert np.linalg.norm(np.array(viewer.player.robot.position)[:2] - robot0[:2]) > 0.2
        moved = settled(page, ok=lambda a: changed_fraction(start, a) > 0.0005)
        assert changed_fraction(start, moved) > 0.0005, "the robot did not move on the page"
        assert page.get_by_text("robot camera").count()
    finally:
        viewer.stop()


def test_registry_page_lists_scenes_and_opens_one(world, page) -> None:
    registry, _, _, checkouts = world
    viewer = open_viewer(registry=registry, port=free_port(), budget=BUDGET, checkouts=checkouts)
    try:
        page.goto(viewer.url)
        page.wait_for_selector("canvas", timeout=120_000)
        page.get_by_text("Registry: 1 scenes").wait_for(timeout=60_000)
        assert page.get_by_text("split:").count() and page.get_by_role("img").count()  # entry and its preview
        empty = settled(page)
        page.get_by_role("button", name=f"Open {SCENE}").click()
        deadline = time.monotonic() + 60
        while viewer.layers is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert viewer.layers is not None and viewer.layers.scene_id == SCENE
        shown = settled(page, ok=lambda a: changed_fraction(empty, a) > 0.05)
        assert changed_fraction(empty, shown) > 0.05, "opening the scene did not draw it"
    finally:
        viewer.stop()
