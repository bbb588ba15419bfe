"""Exports of a COLMAP reconstruction for other tools.

- `write_colmap(rec, folder)`: a binary COLMAP model (cameras.bin, images.bin, points3D.bin).
- `write_transforms(rec, path, ...)`: a nerfstudio-style `transforms.json` for a PINHOLE /
  SIMPLE_PINHOLE model (the undistorted one): shared intrinsics, one frame per registered image
  with a 4x4 camera-to-world `transform_matrix` in OpenGL axes (x right, y up, z back), as
  nerfstudio's `ns-process-data` writes it.
- `rec_cam_to_world(rec)`: name -> 4x4 camera-to-world (OpenCV axes) of registered images.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional

import numpy as np

OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])  # flips camera y and z axes


def write_colmap(rec: Any, folder: Path) -> Path:
    """Write `rec` (pycolmap.Reconstruction) as a binary COLMAP model into `folder`."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rec.write_binary(str(folder))
    return folder


def rec_cam_to_world(rec: Any) -> dict[str, np.ndarray]:
    """Image name -> camera-to-world [4, 4] (OpenCV axes) for registered images."""
    out = {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        T = np.eye(4)
        T[:3, :4] = image.cam_from_world().inverse().matrix()
        out[image.name] = T
    return out


def pinhole_intrinsics(camera: Any) -> dict[str, float]:
    """fl_x, fl_y, cx, cy, w, h of a PINHOLE or SIMPLE_PINHOLE pycolmap camera."""
    name, p = camera.model.name, list(camera.params)
    if name == "SIMPLE_PINHOLE":
        fx = fy = p[0]
        cx, cy = p[1], p[2]
    elif name == "PINHOLE":
        fx, fy, cx, cy = p[:4]
    else:
        raise ValueError(f"transforms.json needs an undistorted pinhole camera, got {name}")
    return {"fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": camera.width, "h": camera.height}


def write_transforms(rec: Any, path: Path, images_prefix: str = "images",
                     masks_prefix: Optional[str] = None,
                     mask_names: Optional[set[str]] = None) -> Path:
    """nerfstudio `transforms.json` for an undistorted single-camera reconstruction.

    File paths are relative to the json's folder: `<images_prefix>/<name>` and, for images
    whose mask exists (`mask_names`), `<masks_prefix>/<name>.png` (0 = ignore in nerfstudio).
    """
    cams = list(rec.cameras.values())
    if len(cams) != 1:
        raise ValueError(f"transforms.json expects one shared camera, got {len(cams)}")
    data: dict[str, Any] = {"camera_model": "OPENCV", **pinhole_intrinsics(cams[0]),
                            "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": []}
    for name, c2w in sorted(rec_cam_to_world(rec).items()):
        frame = {"file_path": f"{images_prefix}/{name}",
                 "transform_matrix": (c2w @ OPENCV_TO_OPENGL).tolist()}
        if masks_prefix and (mask_names is None or name in mask_names):
            frame["mask_path"] = f"{masks_prefix}/{name}.png"
        data["frames"].append(frame)
    path = Path(path)
    path.write_text(json.dumps(data, indent=2))
    return path
