"""Ground-truth scene bundle from a synthetic street: flat splats sampled on the GT mesh.

Reads a StreetScene and its rendered SyntheticClip; writes a registry scene bundle
(vid2sim.formats.bundle format): splats.ply (3DGS, flat Gaussians oriented with the surface,
DC colour from the procedural texture), collision.ply (GT mesh without ground), walkable.npz
(GT sidewalk minus obstacle footprints), cameras.parquet (GT poses), preview.png, plus extras
visual_mesh.ply (the GT mesh with per-face material/colour) and ground_truth.json.
"""

from __future__ import annotations

import hashlib
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from vid2sim.factory.synthetic.geometry import face_areas, face_normals
from vid2sim.factory.synthetic.mesh_io import write_mesh_ply
from vid2sim.factory.synthetic.render import StreetRenderer, SyntheticClip
from vid2sim.factory.synthetic.street import StreetScene
from vid2sim.factory.synthetic.textures import albedo, shade
from vid2sim.factory.synthetic.trajectory import walking_poses
from vid2sim.formats.bundle import COLLISION_PLY, PREVIEW_PNG, VISUAL_MESH_PLY, write_bundle
from vid2sim.formats.scene import make_scene_json
from vid2sim.formats.splat_ply import SPLATS_PLY
from vid2sim.ranges import checked
from vid2sim.splats.model import GaussianModel
from vid2sim.splats.ply import write_ply
from vid2sim.splats.sh import num_sh_coeffs, rgb_to_sh0


@checked
@dataclass(frozen=True)
class GTBundleConfig:
    n_splats: int = 200_000
    x_pad: float = 20.0  # splats cover the walked street +- this many metres
    sh_degree: int = 0
    opacity: float = 0.98
    thickness: float = 0.004  # m, Gaussian extent along the surface normal
    scene_id: str = ""  # default: synthetic-street-s<seed>


def visible_faces(scene: StreetScene, conf: GTBundleConfig, n_views: int = 24) -> np.ndarray:
    """Mask [F] of faces seen from the walked path (low-res casts, looking forward and back)."""
    c = replace(scene.config, width=160, height=90, hfov_deg=100.0)
    r = StreetRenderer(scene, c)
    _, T = walking_poses(replace(c, fps=n_views / c.duration_s))
    seen = np.zeros(scene.n_faces, bool)
    back = np.diag([-1.0, 1.0, -1.0])  # turn around (yaw 180 degrees) about the camera y axis
    for pose in T:
        for R in (pose[:3, :3], pose[:3, :3] @ back):
            P = pose.copy()
            P[:3, :3] = R
            ids = r.primitive_ids(P)
            seen[ids[ids < scene.n_faces]] = True
    return seen


def sample_splats(scene: StreetScene, conf: GTBundleConfig) -> dict[str, np.ndarray]:
    """Area-uniform flat Gaussians on the mesh near the street; arrays keyed like GaussianModel."""
    c = scene.config
    rng = np.random.default_rng(c.seed + 202)
    V, F = scene.vertices, scene.triangles
    # clip the sampling region: only faces overlapping the street's x window, area counted inside it
    lo, hi = -conf.x_pad, c.length_m + conf.x_pad
    fx0, fx1 = V[F][:, :, 0].min(1), V[F][:, :, 0].max(1)
    frac = np.clip((np.minimum(fx1, hi) - np.maximum(fx0, lo)) / np.maximum(fx1 - fx0, 1e-9), 0, 1)
    frac = np.where(fx1 - fx0 < 1e-9, ((fx0 >= lo) & (fx0 <= hi)).astype(float), frac)
    area = face_areas(V, F) * frac * visible_faces(scene, conf)
    total = area.sum()
    spacing = float(np.sqrt(total / conf.n_splats))
    p, fid = np.zeros((0, 3)), np.zeros(0, np.int64)
    while len(p) < conf.n_splats:  # rejection: keep samples inside the x window
        f = rng.choice(len(F), size=2 * conf.n_splats, p=area / total)
        r1, r2 = rng.random((2, len(f)))
        s = np.sqrt(r1)
        a, b, cc = (V[F[f, k]] for k in range(3))
        q = (1 - s)[:, None] * a + (s * (1 - r2))[:, None] * b + (s * r2)[:, None] * cc
        keep = (q[:, 0] >= lo) & (q[:, 0] <= hi)
        p, fid = np.concatenate([p, q[keep]]), np.concatenate([fid, f[keep]])
    p, fid = p[: conf.n_splats], fid[: conf.n_splats]
    n = face_normals(V, F)[fid]  # [N, 3]
    rgb = shade(albedo(p, n, scene.face_material[fid], scene.face_color[fid], scene.face_instance[fid],
                       np.full(len(p), spacing), c), n, c)
    # local frame: columns (t1, t2, n) -> quaternion (w, x, y, z)
    axis = np.where(np.abs(n[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t1 = np.cross(axis, n)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    xyzw = Rotation.from_matrix(np.stack([t1, t2, n], axis=2)).as_quat()
    quats = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], 1)
    log_scales = np.log(np.tile([0.75 * spacing, 0.75 * spacing, conf.thickness], (len(p), 1)))
    return {"means": p, "quats": quats, "log_scales": log_scales, "normals": n,
            "rgb": np.clip(rgb, 0, 1), "spacing": np.float64(spacing)}


def _gaussian_model(s: dict, conf: GTBundleConfig):
    t = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    n = len(s["means"])
    sh = torch.zeros(n, num_sh_coeffs(conf.sh_degree), 3)
    sh[:, 0] = rgb_to_sh0(t(s["rgb"]))
    logit = float(np.log(conf.opacity / (1 - conf.opacity)))
    return GaussianModel(means=t(s["means"]), quats=t(s["quats"]), log_scales=t(s["log_scales"]),
                         opacity_logits=torch.full((n,), logit), sh=sh)


def _preview(scene: StreetScene, clip: SyntheticClip, path: Path) -> Path:
    """An elevated view down the street from behind the first camera."""
    T = clip.cam_to_world[0].copy()
    pitch = np.deg2rad(20.0)  # extra downward tilt about the camera x axis
    Rx = np.array([[1, 0, 0], [0, np.cos(pitch), -np.sin(pitch)], [0, np.sin(pitch), np.cos(pitch)]])
    T[:3, :3] = T[:3, :3] @ Rx
    T[:3, 3] += np.array([-4.0, -0.5, 2.5])
    img = StreetRenderer(scene, replace(scene.config, width=640, height=360)).render(T)["rgb"]
    cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    return path


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_ground_truth_bundle(scene: StreetScene, clip: SyntheticClip, out_dir: Path,
                              conf: GTBundleConfig = GTBundleConfig(), overwrite: bool = True) -> Path:
    """Write the GT scene bundle to out_dir (validated by the registry's validate_bundle)."""
    c = scene.config
    splats = sample_splats(scene, conf)
    grid, origin, res = scene.walkable_grid()
    scene_id = conf.scene_id or f"synthetic-street-s{c.seed}"
    metrics = {"ground_truth": True, "n_frames": len(clip.cam_to_world), "n_splats": len(splats["means"]),
               "splat_spacing_m": float(splats["spacing"]), "path_length_m": clip.ground_truth["path_length"],
               "walkable_area_m2": float(grid.sum() * res * res), "capture_height_m": c.capture_height}
    scene_json = make_scene_json(
        scene_id, source_uri=f"synthetic://street?seed={c.seed}", source_sha256=_sha256(clip.video),
        clip_start_s=0.0, clip_end_s=float(c.duration_s), group=f"synthetic-street-s{c.seed}",
        scale_source="synthetic_gt", metrics=metrics, config={"street": c, "bundle": conf},
        tags=["synthetic", "ground_truth"], description="Procedural sidewalk street with exact ground truth")
    with tempfile.TemporaryDirectory(prefix="gt-bundle-") as tmp:
        tmp = Path(tmp)
        write_ply(_gaussian_model(splats, conf), tmp / SPLATS_PLY)
        v, f = scene.without_ground()
        write_mesh_ply(tmp / COLLISION_PLY, v, f)
        write_mesh_ply(tmp / VISUAL_MESH_PLY, scene.vertices, scene.triangles, scene.face_material,
                       scene.face_color, scene.face_instance)
        _preview(scene, clip, tmp / PREVIEW_PNG)
        extras = {VISUAL_MESH_PLY: tmp / VISUAL_MESH_PLY,
                  "ground_truth.json": clip.out_dir / "ground_truth.json"}
        return write_bundle(out_dir, scene_json=scene_json, splats_ply=tmp / SPLATS_PLY,
                            collision_ply=tmp / COLLISION_PLY, walkable=(grid, origin, res),
                            cameras=clip.posed.cameras_table(), preview_png=tmp / PREVIEW_PNG,
                            extras=extras, overwrite=overwrite)
