"""RecordEpisode writes decodable MP4s (view beside top-down map), one frame per reset/step."""

from __future__ import annotations

import cv2
import numpy as np

from envs_grid_nav import GridNavEnv
from vid2sim.envs.recording import MAP_W, PANEL_H, RecordEpisode, TopdownMap, record_episodes


def _frames(path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    cap.release()
    return out


def _run(env, episodes: int, rng: np.random.Generator) -> list[int]:
    lengths = []
    for k in range(episodes):
        env.reset(seed=k)
        n, done = 0, False
        while not done:
            _, _, term, trunc, _ = env.step(rng.uniform([0.3, -0.3], [1.0, 0.3]))
            n, done = n + 1, term or trunc
        lengths.append(n)
    return lengths


def test_writes_one_decodable_mp4_per_episode(tmp_path) -> None:
    env = RecordEpisode(GridNavEnv(max_steps=12), tmp_path, fps=5)
    lengths = _run(env, 2, np.random.default_rng(0))
    env.close()
    assert [p.name for p in env.paths] == ["episode-0.mp4", "episode-1.mp4"]
    for path, n in zip(env.paths, lengths):
        frames = _frames(path)
        assert len(frames) == n + 1  # the reset frame and one per step
        f = frames[-1]
        assert f.shape[0] == PANEL_H and f.shape[1] > 2 * PANEL_H
        view_w = int(round(128 * PANEL_H / 72))
        assert f[:, :view_w].std() > 5  # the camera view is not blank
        mp = f[:, view_w:].astype(int)
        yellow = (mp[..., 1] > 180) & (mp[..., 2] > 180) & (mp[..., 0] < 100)  # robot (BGR)
        green = (mp[..., 1] > 150) & (mp[..., 0] < 100) & (mp[..., 2] < 100)  # path taken
        assert yellow.sum() > 20 and green.sum() > 20
    assert not np.array_equal(_frames(env.paths[0])[0], _frames(env.paths[0])[-1])  # it moved


def test_episode_trigger_selects_episodes(tmp_path) -> None:
    env = RecordEpisode(GridNavEnv(max_steps=4, render_mode=None), tmp_path,
                        episode_trigger=lambda k: k % 2 == 1)
    lengths = _run(env, 3, np.random.default_rng(1))
    env.close()
    assert [p.name for p in env.paths] == ["episode-1.mp4"]
    assert len(_frames(env.paths[0])) == lengths[1] + 1  # view taken from obs["image"]


class _GoalSeeker:
    """Turns towards the goal and drives (the toy env's vector is distance, bearing)."""

    def reset(self, env) -> None:
        self.steps = 0

    def act(self, env) -> np.ndarray:
        u = env.unwrapped
        d = u.goal - u.xy
        bearing = (np.arctan2(d[1], d[0]) - u.yaw + np.pi) % (2 * np.pi) - np.pi
        return np.array([1.0, np.clip(bearing / 0.3, -1, 1)], np.float32)


def test_record_episodes_runs_an_agent_to_the_end(tmp_path) -> None:
    paths = record_episodes(GridNavEnv(max_steps=40), tmp_path / "videos", 2, _GoalSeeker())
    assert [p.name for p in paths] == ["episode-0.mp4", "episode-1.mp4"]
    n = len(_frames(paths[0]))
    assert 20 < n < 41  # 8 m at 0.3 m per step: the episode ends at the goal, before the limit


def test_map_zooms_on_the_episode_of_a_long_street() -> None:
    grid = np.ones((25, 450), np.uint8)  # 45 m x 2.5 m street
    ends = np.array([[10.0, 1.0], [20.0, 1.5]])
    whole = TopdownMap(grid, (0.0, 0.0), 0.1)
    zoom = TopdownMap(grid, (0.0, 0.0), 0.1, focus=ends)
    for m in (whole, zoom):
        assert m.base.shape == (PANEL_H, MAP_W, 3)
        p = m.px(ends)
        assert ((p >= 0) & (p < [MAP_W, PANEL_H])).all()
        assert p[0, 1] > p[1, 1]  # +y is up on the map
    span = lambda m: np.diff(m.px(ends)[:, 0])[0]  # noqa: E731
    assert span(zoom) > 1.5 * span(whole) and span(whole) > 100


def test_a_trace_beside_each_mp4_has_one_step_per_frame(tmp_path) -> None:
    from vid2sim.formats.episode_trace import read_trace, trace_path

    env = RecordEpisode(GridNavEnv(max_steps=12), tmp_path, fps=5)
    lengths = _run(env, 1, np.random.default_rng(0))
    env.close()
    trace = read_trace(trace_path(env.paths[0]))
    assert trace.steps == lengths[0] + 1 == len(_frames(env.paths[0]))
    assert trace.video == "episode-0.mp4" and trace.view_width_px == int(round(128 * PANEL_H / 72))
    assert trace.xy[0] != trace.xy[-1] and len(trace.goal) == 2 and trace.fps == 5
