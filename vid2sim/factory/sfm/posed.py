"""PosedClip: the hand-over from SfM/alignment (or a synthetic ground truth) to
reconstruction and meshing.

On disk (a folder):
  cameras.parquet  one row per frame, schema `vid2sim.formats.cameras.cameras_schema()`
  points.npz       xyz [M, 3] float64 (world), rgb [M, 3] uint8  (sparse SfM points)
  frame.json       world-frame facts: units, up axis, ground z, scale source, extras
Images live in `images_dir` (pinhole, undistorted) and masks in `masks_dir`
(mask for image `a.jpg` is `a.jpg.png`, uint8, 0 = dynamic/ignored, 255 = static).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vid2sim.formats.cameras import CAMERA_COLUMNS, CAMERAS_PARQUET, cameras_schema

def holdout_split(n: int, every: int = 8) -> list[str]:
    """Paper protocol: every 8th frame (index % 8 == 0) is held out for testing."""
    return ["test" if i % every == 0 else "train" for i in range(n)]


@dataclass
class PosedFrame:
    index: int
    image: str
    timestamp: float
    width: int
    height: int
    K: np.ndarray  # [3, 3]
    cam_to_world: np.ndarray  # [4, 4] OpenCV axes
    split: str = "train"


def portable_path(target: Path, folder: Path) -> str:
    """`target` relative to `folder` (both resolved): stage folders are siblings under one clip
    folder, so a relative path stays valid when the clip folder moves to another node's scratch."""
    return os.path.relpath(Path(target).resolve(), Path(folder).resolve())


@dataclass
class PosedClip:
    frames: list[PosedFrame]
    images_dir: Path
    masks_dir: Optional[Path] = None
    points_xyz: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # [M, 3]
    points_rgb: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))  # [M, 3]
    frame_info: dict = field(default_factory=dict)

    def split(self, name: str) -> list[PosedFrame]:
        return [f for f in self.frames if f.split == name]

    def image_path(self, frame: PosedFrame) -> Path:
        return Path(self.images_dir) / frame.image

    def mask_path(self, frame: PosedFrame) -> Optional[Path]:
        if self.masks_dir is None:
            return None
        p = Path(self.masks_dir) / f"{frame.image}.png"
        return p if p.exists() else None

    def cameras_table(self) -> pa.Table:
        rows = {c: [] for c in CAMERA_COLUMNS}
        for f in self.frames:
            rows["index"].append(f.index)
            rows["image"].append(f.image)
            rows["timestamp"].append(float(f.timestamp))
            rows["width"].append(int(f.width))
            rows["height"].append(int(f.height))
            rows["fx"].append(float(f.K[0, 0]))
            rows["fy"].append(float(f.K[1, 1]))
            rows["cx"].append(float(f.K[0, 2]))
            rows["cy"].append(float(f.K[1, 2]))
            rows["cam_to_world"].append(np.asarray(f.cam_to_world, np.float64).reshape(16).tolist())
            rows["split"].append(f.split)
        return pa.Table.from_pydict(rows, schema=cameras_schema())

    def save(self, folder: Path) -> Path:
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        pq.write_table(self.cameras_table(), folder / CAMERAS_PARQUET)
        np.savez(folder / "points.npz", xyz=np.asarray(self.points_xyz, np.float64),
                 rgb=np.asarray(self.points_rgb, np.uint8))
        info = dict(self.frame_info)
        info["images_dir"] = portable_path(self.images_dir, folder)
        info["masks_dir"] = portable_path(self.masks_dir, folder) if self.masks_dir else None
        (folder / "frame.json").write_text(json.dumps(info, indent=2))
        return folder

    @classmethod
    def load(cls, folder: Path) -> "PosedClip":
        folder = Path(folder)
        table = pq.read_table(folder / CAMERAS_PARQUET).to_pylist()
        frames = []
        for r in table:
            K = np.array([[r["fx"], 0, r["cx"]], [0, r["fy"], r["cy"]], [0, 0, 1]], np.float64)
            frames.append(PosedFrame(r["index"], r["image"], r["timestamp"], r["width"], r["height"],
                                     K, np.array(r["cam_to_world"], np.float64).reshape(4, 4), r["split"]))
        pts = np.load(folder / "points.npz")
        info = json.loads((folder / "frame.json").read_text())
        masks = info.pop("masks_dir", None)
        return cls(frames=frames, images_dir=folder / info.pop("images_dir"),
                   masks_dir=folder / masks if masks else None,
                   points_xyz=pts["xyz"], points_rgb=pts["rgb"], frame_info=info)
