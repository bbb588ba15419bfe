"""Image augmentation for the env camera, randomised once per episode.

Photometric: exposure (EV stops), white balance (red/blue gains), time-of-day tint (day,
golden hour, dusk, night). Weather: depth-based fog (Koschmieder: t = exp(-density x depth),
empty / sky pixels count as infinitely far), and depth-aware rain and snow: each particle
has a depth and is drawn only where the scene behind it is farther, so it passes behind
nearer geometry; streak length and flake size shrink with the particle's depth.

`Augmenter.reset(rng)` draws the episode's parameters (`EpisodeAugment`) and a private
generator for the per-frame particles, so a seed gives the same images every time.
`AugmentConfig.enabled` is False by default (evaluation); the env config turns it on for
training.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import math

import numpy as np
from numba import njit

from vid2sim.ranges import checked

TINTS = {  # per-channel RGB gain and overall brightness
    "day": ((1.0, 1.0, 1.0), 1.0),
    "golden": ((1.12, 0.98, 0.80), 0.95),
    "dusk": ((1.0, 0.85, 0.95), 0.7),
    "night": ((0.75, 0.85, 1.15), 0.45),
}


@checked
@dataclass
class AugmentConfig:
    """Ranges and probabilities of the per-episode augmentation."""

    enabled: bool = False  # augment at all (EnvConfig.augment None: on when training)
    exposure_ev: tuple[float, float] = (-0.7, 0.7)  # exposure change range, in stops (EV)
    white_balance: tuple[float, float] = (0.85, 1.15)  # red and blue gains, green fixed
    tints: tuple[str, ...] = ("day", "day", "golden", "dusk", "night")  # sampled uniformly
    fog_prob: float = 0.25  # probability of fog in an episode
    fog_density: tuple[float, float] = (0.03, 0.25)  # 1/m, fog density range (transmittance exp(-density x depth))
    fog_color: tuple[int, int, int] = (200, 203, 208)  # RGB (0-255) the fog blends towards
    rain_prob: float = 0.15  # probability of rain in an episode
    snow_prob: float = 0.1  # probability of snow in an episode (exclusive with rain)
    particles: tuple[int, int] = (80, 300)  # per frame at 128x72 (scaled with image area)
    particle_depth: tuple[float, float] = (0.3, 10.0)  # m, depth range of rain / snow particles


@dataclass
class EpisodeAugment:
    """One episode's drawn augmentation parameters."""

    gain: np.ndarray  # [3] exposure x white balance x tint, per channel
    tint: str
    fog_density: float  # 0 = no fog
    weather: str  # "clear", "rain" or "snow"
    particles: int
    wind: float  # rain slant (pixels across per pixel down)


class Augmenter:
    """Applies one episode's augmentation to (rgb, depth) frames."""

    def __init__(self, config: Optional[AugmentConfig] = None) -> None:
        self.config = config or AugmentConfig()
        self.params: Optional[EpisodeAugment] = None
        self._rng = np.random.default_rng(0)

    def reset(self, rng: np.random.Generator) -> Optional[EpisodeAugment]:
        """Draw this episode's parameters from rng (nothing when disabled)."""
        c = self.config
        if not c.enabled:
            self.params = None
            return None
        ev = rng.uniform(*c.exposure_ev)
        wb = np.array([rng.uniform(*c.white_balance), 1.0, rng.uniform(*c.white_balance)])
        tint = str(c.tints[int(rng.integers(len(c.tints)))])
        tint_gain, bright = TINTS[tint]
        fog = rng.uniform(*c.fog_density) if rng.random() < c.fog_prob else 0.0
        u = rng.random()
        weather = "rain" if u < c.rain_prob else "snow" if u < c.rain_prob + c.snow_prob else "clear"
        self.params = EpisodeAugment(
            gain=(2.0 ** ev) * wb * np.array(tint_gain) * bright, tint=tint, fog_density=float(fog),
            weather=weather, particles=int(rng.integers(c.particles[0], c.particles[1] + 1)),
            wind=float(rng.uniform(-0.3, 0.3)))
        self._rng = np.random.default_rng(rng.integers(2**63))
        return self.params

    def apply(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Augmented copy of rgb [H, W, 3] u8 given its camera depth [H, W] (m; <= 0 or inf =
        empty): exposure, tint and fog in one numba pass (`_tone`), then the particles; equals
        `apply_reference` up to float rounding (one level at most)."""
        if self.params is None:
            return rgb
        p = self.params
        color = np.array(self.config.fog_color, np.float32) * np.float32(p.gain.mean())
        rgb8 = np.ascontiguousarray(rgb, dtype=np.uint8)
        d = np.ascontiguousarray(depth, dtype=np.float32)
        if p.weather == "clear":
            out = np.empty(rgb8.shape, np.uint8)
            _tone(rgb8, d, p.gain.astype(np.float32), np.float32(p.fog_density), color, out,
                  np.empty((0, 0, 3), np.float32))
            return out
        img = np.empty(rgb8.shape, np.float32)
        _tone(rgb8, d, p.gain.astype(np.float32), np.float32(p.fog_density), color,
              np.empty((0, 0, 3), np.uint8), img)
        far = np.where((d > 0) & np.isfinite(d), d, np.float32(np.inf))  # [H, W]
        scale = rgb.shape[0] * rgb.shape[1] / (128 * 72)
        img = particles(img, far, self._rng, int(p.particles * scale), p.weather, p.wind,
                        self.config.particle_depth)
        return np.clip(img, 0, 255).round().astype(np.uint8)

    def apply_reference(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """`apply` in plain numpy (the reference it is tested against)."""
        if self.params is None:
            return rgb
        p = self.params
        far = np.where((depth > 0) & np.isfinite(depth), depth, np.inf).astype(np.float32)  # [H, W]
        img = rgb.astype(np.float32) * p.gain.astype(np.float32)  # [H, W, 3]
        if p.fog_density > 0:
            img = fog(img, far, p.fog_density, np.array(self.config.fog_color, np.float32) * p.gain.mean())
        if p.weather != "clear":
            scale = rgb.shape[0] * rgb.shape[1] / (128 * 72)
            img = particles(img, far, self._rng, int(p.particles * scale), p.weather, p.wind,
                            self.config.particle_depth)
        return np.clip(img, 0, 255).round().astype(np.uint8)


@njit(cache=True)
def _tone(rgb, depth, gain, density, color, out_u8, out_f32):
    """rgb [H, W, 3] u8 x gain [3], blended towards color [3] by the Koschmieder transmittance
    exp(-density x depth) where density > 0 (depth [H, W]: <= 0, NaN or inf = infinitely far),
    in float32; written rounded and clipped to out_u8 [H, W, 3] when it has pixels, else to
    out_f32 [H, W, 3]."""
    H, W = depth.shape
    to_u8 = out_u8.shape[0] > 0
    for i in range(H):
        for j in range(W):
            t = np.float32(1.0)
            if density > 0:
                z = depth[i, j]
                t = np.float32(math.exp(-density * z)) if z > 0 and z < np.inf else np.float32(0.0)
            for c in range(3):
                v = np.float32(rgb[i, j, c]) * gain[c]
                if density > 0:
                    v = v * t + color[c] * (np.float32(1.0) - t)
                if to_u8:
                    out_u8[i, j, c] = np.uint8(np.rint(min(max(v, np.float32(0.0)), np.float32(255.0))))
                else:
                    out_f32[i, j, c] = v


def fog(img: np.ndarray, depth: np.ndarray, density: float, color: np.ndarray) -> np.ndarray:
    """Koschmieder fog: img [H, W, 3] f32 blended to color by t = exp(-density x depth [H, W])."""
    t = np.exp(-density * depth)[..., None]  # [H, W, 1]; inf depth -> 0
    return img * t + color * (1.0 - t)


def particles(img: np.ndarray, depth: np.ndarray, rng: np.random.Generator, count: int,
              kind: str, wind: float, depth_range: tuple[float, float]) -> np.ndarray:
    """Draw `count` rain streaks or snow flakes, each hidden where the scene is nearer than it."""
    H, W = depth.shape
    z = rng.uniform(*depth_range, size=count)  # [N] particle depths
    u0 = rng.uniform(0, W, size=count)
    v0 = rng.uniform(0, H, size=count)
    if kind == "rain":
        length = np.clip(12.0 / z * H / 72, 1, H / 3)  # px
        k = np.arange(int(np.ceil(length.max())))  # [L]
        on = k[None] < length[:, None]  # [N, L]
        us, vs = u0[:, None] + wind * k[None], v0[:, None] + k[None]
        color, alpha = np.array([210, 215, 225], np.float32), 0.35
    elif kind == "snow":
        r = np.clip(1.2 / z * H / 72, 0, 2).round().astype(int)  # px radius
        offs = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]])  # [5, 2]
        on = (np.abs(offs).sum(1)[None] <= r[:, None])  # [N, 5]
        us, vs = u0[:, None] + offs[None, :, 0], v0[:, None] + offs[None, :, 1]
        color, alpha = np.array([245, 245, 250], np.float32), 0.85
    else:
        raise ValueError(f"unknown particle kind {kind!r}; choose rain or snow")
    ui, vi = np.floor(us).astype(int), np.floor(vs).astype(int)
    zz = np.broadcast_to(z[:, None], on.shape)
    ok = on & (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H)
    ui, vi, zz = ui[ok], vi[ok], zz[ok]
    visible = depth[vi, ui] > zz  # the scene behind the particle is farther
    out = img.copy()
    out[vi[visible], ui[visible]] = (1 - alpha) * out[vi[visible], ui[visible]] + alpha * color
    return out
