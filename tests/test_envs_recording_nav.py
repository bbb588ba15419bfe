"""RecordEpisode / record_episodes on the real NavEnv (synthetic street GT bundle, SocialNav)."""

from __future__ import annotations

import cv2
import gymnasium
import pytest

import vid2sim.envs  # noqa: F401  (registers the env ids)
from vid2sim.envs.expert import PurePursuitExpert
from vid2sim.envs.recording import PANEL_H, record_episodes
from vid2sim.factory.synthetic import GTBundleConfig, generate_street, preset, render_video, write_ground_truth_bundle
from vid2sim.registry import Registry


def _count_frames(path) -> tuple[int, tuple[int, ...]]:
    cap = cv2.VideoCapture(str(path))
    n, shape = 0, ()
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        n, shape = n + 1, frame.shape
    cap.release()
    return n, shape


@pytest.mark.slow
def test_expert_socialnav_episode_is_recorded(tmp_path) -> None:
    conf = preset("test", seed=11)
    scene = generate_street(conf)
    clip = render_video(scene, conf, tmp_path / "clip")
    bundle = write_ground_truth_bundle(scene, clip, tmp_path / "bundle", GTBundleConfig(n_splats=20_000))
    reg = Registry(tmp_path / "registry")
    reg.add(bundle)
    env = gymnasium.make("vid2sim/SocialNav-v0", registry=reg.root, scenes="synthetic-street-s11",
                         checkout_root=tmp_path / "co", training=False)
    steps: list[int] = []

    class CountingExpert(PurePursuitExpert):
        def act(self, e):
            steps[-1] += 1
            return super().act(e)

        def reset(self, e):
            steps.append(0)
            super().reset(e)

    paths = record_episodes(env, tmp_path / "videos", 1, CountingExpert(), seed=3)
    n, shape = _count_frames(paths[0])
    assert n == steps[0] + 1 and steps[0] > 5
    assert shape[0] == PANEL_H
