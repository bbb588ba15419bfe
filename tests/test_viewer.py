"""The viewer's inputs without a browser: layers of a bundle (one missing), the splat budget,
the scene card, scene ids against a registry, the port check, episode traces and reports."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest
from registry_fixtures import make_bundle

from vid2sim.formats.episode_trace import EpisodeTrace, read_trace, trace_path
from vid2sim.formats.errors import BundleError
from vid2sim.registry import Registry
from vid2sim.viewer.app import open_viewer
from vid2sim.viewer.card import scene_card
from vid2sim.viewer.episode import resolve_episode
from vid2sim.viewer.errors import EpisodeInputError, NotABundle, PortInUse, UnknownScene
from vid2sim.viewer.layers import load_layers
from vid2sim.viewer.server import check_port_free
from vid2sim.viewer.source import resolve_bundle
from vid2sim.viewer.splats import covariances, keep_mask, read_splat_layer


@pytest.fixture
def bundle(tmp_path):
    return make_bundle(tmp_path / "b", "scene-a", n_splats=400, metrics={"corridor.walkable_fraction": 0.99,
                                                                          "recon.psnr": 27.5})


def test_all_layers_load(bundle) -> None:
    layers = load_layers(bundle)
    assert layers.missing == {} and layers.scene_id == "scene-a"
    assert layers.splats.shown == layers.splats.total == 400
    assert len(layers.mesh.faces) == 12 and layers.walkable.grid.sum() == 36
    assert layers.cameras.centers.shape == (16, 3)
    lo, hi = layers.bounds()
    assert (hi > lo).all()


def test_missing_layer_is_named_and_the_rest_shown(bundle) -> None:
    (bundle / "collision.ply").unlink()
    layers = load_layers(bundle)
    assert list(layers.missing) == ["collision.ply"] and "missing collision mesh" in layers.missing["collision.ply"]
    assert layers.mesh is None and layers.splats is not None and layers.walkable is not None
    assert "Missing layers" in scene_card(layers.scene, layers.splats, layers.missing)


def test_folder_without_layers_is_not_a_bundle(tmp_path) -> None:
    with pytest.raises(NotABundle, match="not a scene bundle"):
        load_layers(tmp_path)


def test_splat_budget_keeps_the_largest_opaque_gaussians(bundle) -> None:
    layer = read_splat_layer(bundle / "splats.ply", budget=50)
    assert layer.shown == 50 and layer.total == 400
    opacity = np.array([0.9, 0.1, 0.9, 0.9])
    scales = np.array([[1, 1, 1], [5, 5, 5], [0.1, 0.1, 0.1], [2, 2, 0.01]], float)
    assert keep_mask(opacity, scales, 2).tolist() == [1, 3]  # scores 0.9, 2.5, 0.009, 3.6


def test_covariance_of_a_rotated_gaussian() -> None:
    quat = np.array([[np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)]])  # 90 deg about z
    cov = covariances(quat, np.array([[2.0, 1.0, 0.5]]))[0]
    assert np.allclose(np.diag(cov), [1.0, 4.0, 0.25], atol=1e-6)


def test_scene_card_shows_source_licence_and_corridor(bundle) -> None:
    layers = load_layers(bundle)
    card = scene_card(layers.scene, layers.splats, layers.missing)
    assert "file:///videos/scene-a.mp4" in card and "Walked corridor" in card and "walkable_fraction" in card
    assert "400 of 400" in card


def test_scene_id_from_registry_and_unknown_id(tmp_path, bundle) -> None:
    reg = Registry(tmp_path / "reg")
    reg.add(bundle)
    out = resolve_bundle("scene-a", str(reg.root), tmp_path / "co")
    assert (out / "splats.ply").is_file() and out.parent == tmp_path / "co"
    with pytest.raises(UnknownScene, match="unknown scene 'nope'.*scene-a"):
        resolve_bundle("nope", str(reg.root), tmp_path / "co")
    with pytest.raises(UnknownScene, match="no registry there"):
        resolve_bundle("nope", str(tmp_path / "empty"))


def test_port_in_use_is_named() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(PortInUse, match=f"port {port}"):
            check_port_free("127.0.0.1", port)


def test_bad_input_fails_before_a_server_starts(tmp_path, bundle) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        with pytest.raises(PortInUse):
            open_viewer(str(bundle), port=s.getsockname()[1])
    with pytest.raises(EpisodeInputError, match="no such file"):
        open_viewer(episode=tmp_path / "missing.trace.json")


def _trace(tmp_path) -> EpisodeTrace:
    t = EpisodeTrace(scene_id="scene-a", robot={"length_m": 0.9, "width_m": 0.6, "height_m": 0.6},
                     goal=[3.0, 0.0], planned_path=[[0.0, 0.0], [3.0, 0.0]], video="ep.mp4")
    for k in range(4):
        t.append((k, 0.0), 0.0, k == 2, [[1.0, 1.0]], np.zeros((0, 2)))
    t.write(trace_path(tmp_path / "ep.mp4"))
    return t


def test_trace_round_trip_and_report(tmp_path) -> None:
    _trace(tmp_path)
    back = read_trace(tmp_path / "ep.trace.json")
    assert back.steps == 4 and back.collided == [False, False, True, False] and back.obstacles[0] == [[1.0, 1.0]]
    report = tmp_path / "report.json"
    report.write_text(json.dumps({"videos": [str(tmp_path / "ep.mp4")], "config": {"registry": "R"}}))
    src = resolve_episode(report)
    assert src.trace.steps == 4 and src.registry == "R" and src.video is None  # the MP4 itself is not there
    with pytest.raises(EpisodeInputError, match="episode 3 asked for"):
        resolve_episode(report, 3)


def test_bad_traces_are_named(tmp_path) -> None:
    (tmp_path / "x.trace.json").write_text(json.dumps({"schema": "other"}))
    with pytest.raises(BundleError, match="not an episode trace"):
        read_trace(tmp_path / "x.trace.json")
    (tmp_path / "r.json").write_text(json.dumps({"videos": []}))
    with pytest.raises(EpisodeInputError, match="recorded no episodes"):
        resolve_episode(tmp_path / "r.json")


def test_demo_prints_viewer_commands_that_parse(tmp_path) -> None:
    import shlex

    from vid2sim.cli.demo import viewer_commands

    cmds = viewer_commands(str(tmp_path / "my reg"), "video-abc-0-10s", tmp_path / "ep.trace.json")
    assert shlex.split(cmds[0])[1:] == ["view", "video-abc-0-10s", "--registry", str(tmp_path / "my reg")]
    assert shlex.split(cmds[1])[1:4] == ["view", "--episode", str(tmp_path / "ep.trace.json")]


def test_cli_bad_input_exits_2_naming_it(tmp_path, bundle) -> None:
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    reg = Registry(tmp_path / "reg")
    reg.add(bundle)
    r = CliRunner().invoke(app, ["view", "nope", "--registry", str(reg.root)])
    assert r.exit_code == 2 and "unknown scene 'nope'" in r.output
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = CliRunner().invoke(app, ["view", str(bundle), "--port", str(port)])
    assert r.exit_code == 2 and f"port {port} on 127.0.0.1 is in use" in r.output


def test_walkable_image_rows_follow_the_grid() -> None:
    from vid2sim.viewer.scene_view import walkable_rgba

    grid = np.zeros((4, 3), np.uint8)
    grid[0, 2] = 1  # lowest y, largest x
    img = walkable_rgba(grid)
    assert img.shape == (4, 3, 4) and img[0, 2, 3] > 0 and img[:, :, 3].sum() == img[0, 2, 3]


def test_viewer_on_a_bundle_missing_a_layer_shows_the_rest(bundle) -> None:
    (bundle / "walkable.npz").unlink()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    viewer = open_viewer(str(bundle), port=port)
    try:
        assert viewer.url.endswith(f":{port}")
        assert sorted(viewer.scene.toggles) == ["camera path", "collision mesh", "grid (1 m cells)", "splats"]
        assert len(viewer.messages) == 1 and "walkable.npz: missing walkable grid" in viewer.messages[0]
    finally:
        viewer.stop()
