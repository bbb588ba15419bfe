"""Ground-truth depth / normal / colour rendering of a triangle mesh by ray casting (CPU).

Uses `open3d.t.geometry.RaycastingScene`. Camera conventions match the splat renderer
(docs/splat_renderer.md): pinhole K, camera-to-world [4, 4] with OpenCV axes (x right,
y down, z forward), pixel (row i, col j) centred at (j + 0.5, i + 0.5). Depth is the
camera z (not the ray length), 0 where the ray misses. Normals are in the CAMERA frame,
flipped to face the camera (as the splat renderer's normals).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Union

import numpy as np
import open3d as o3d
import trimesh

MeshLike = Union[trimesh.Trimesh, o3d.geometry.TriangleMesh, tuple]


def mesh_arrays(mesh: MeshLike) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V, 3] float64, faces [F, 3] int64) of a trimesh, open3d mesh or (V, F) tuple."""
    if isinstance(mesh, trimesh.Trimesh):
        return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    if isinstance(mesh, o3d.geometry.TriangleMesh):
        return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.triangles, np.int64)
    if isinstance(mesh, tuple) and len(mesh) == 2:
        return np.asarray(mesh[0], np.float64), np.asarray(mesh[1], np.int64)
    raise TypeError(f"unsupported mesh type {type(mesh).__name__}")


def mesh_vertex_colors(mesh: MeshLike) -> Optional[np.ndarray]:
    """Vertex colours [V, 3] uint8 when the mesh has them, else None."""
    if isinstance(mesh, trimesh.Trimesh):
        if mesh.visual.kind in ("vertex", "face"):  # face colours are averaged to vertices
            return np.asarray(mesh.visual.vertex_colors)[:, :3].astype(np.uint8)
        return None
    if isinstance(mesh, o3d.geometry.TriangleMesh) and mesh.has_vertex_colors():
        return np.clip(np.asarray(mesh.vertex_colors) * 255.0 + 0.5, 0, 255).astype(np.uint8)
    return None


def pixel_rays_cam(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Camera-frame ray directions with z = 1 through each pixel centre: [H, W, 3]."""
    K = np.asarray(K, np.float64)
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)  # [H, W]
    x = (j - K[0, 2] - K[0, 1] * (i - K[1, 2]) / K[1, 1]) / K[0, 0]
    y = (i - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], axis=-1)


@dataclass
class RaycastOutput:
    depth: np.ndarray  # [H, W] float32 camera z, 0 = miss
    normal_cam: np.ndarray  # [H, W, 3] float32, camera frame, facing the camera; 0 = miss
    rgb: Optional[np.ndarray]  # [H, W, 3] uint8 from vertex colours, or None
    face_id: np.ndarray  # [H, W] int64, -1 = miss


class RaycastRenderer:
    """Builds the ray-casting scene once; `render` is then called per camera."""

    def __init__(self, mesh: MeshLike) -> None:
        self.vertices, self.faces = mesh_arrays(mesh)
        if len(self.faces) == 0:
            raise ValueError("cannot ray-cast an empty mesh")
        self.colors = mesh_vertex_colors(mesh)
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(
            o3d.core.Tensor(self.vertices.astype(np.float32)),
            o3d.core.Tensor(self.faces.astype(np.uint32)))

    def render(self, K: np.ndarray, cam_to_world: np.ndarray, width: int,
               height: int) -> RaycastOutput:
        c2w = np.asarray(cam_to_world, np.float64)
        R, t = c2w[:3, :3], c2w[:3, 3]
        d_cam = pixel_rays_cam(K, width, height)  # [H, W, 3], z = 1
        d_world = d_cam @ R.T  # [H, W, 3]; t_hit is then camera z
        rays = np.concatenate([np.broadcast_to(t, d_world.shape), d_world], axis=-1)
        ans = self.scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
        t_hit = ans["t_hit"].numpy()  # [H, W]
        hit = np.isfinite(t_hit)
        depth = np.where(hit, t_hit, 0.0).astype(np.float32)
        n_world = ans["primitive_normals"].numpy().astype(np.float64)  # [H, W, 3]
        n_cam = n_world @ R  # R^T n for each pixel
        flip = np.sum(n_cam * d_cam, axis=-1) > 0
        n_cam[flip] *= -1.0
        n_cam[~hit] = 0.0
        face_id = np.where(hit, ans["primitive_ids"].numpy().astype(np.int64), -1)
        rgb = self._shade(face_id, ans["primitive_uvs"].numpy(), hit)
        return RaycastOutput(depth, n_cam.astype(np.float32), rgb, face_id)

    def _shade(self, face_id: np.ndarray, uvs: np.ndarray, hit: np.ndarray) -> Optional[np.ndarray]:
        """Barycentric interpolation of vertex colours at the hit points."""
        if self.colors is None:
            return None
        rgb = np.zeros(face_id.shape + (3,), np.float64)
        tri = self.faces[face_id[hit]]  # [P, 3]
        u, v = uvs[hit][:, 0:1], uvs[hit][:, 1:2]
        c = self.colors.astype(np.float64)
        rgb[hit] = (1 - u - v) * c[tri[:, 0]] + u * c[tri[:, 1]] + v * c[tri[:, 2]]
        return np.clip(rgb + 0.5, 0, 255).astype(np.uint8)


def render_depth_normals(mesh: MeshLike, K: np.ndarray, cam_to_world: np.ndarray,
                         width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """One-shot convenience function: (depth [H, W] float32 camera z, normal_cam [H, W, 3] float32)."""
    out = RaycastRenderer(mesh).render(K, cam_to_world, width, height)
    return out.depth, out.normal_cam


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])
            ) -> np.ndarray:
    """Camera-to-world [4, 4] (OpenCV axes) at `eye` looking at `target`, world `up`."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: viewing direction is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    return c2w
