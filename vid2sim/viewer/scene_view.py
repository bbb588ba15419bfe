"""Draws SceneLayers into a viser scene: splats, collision mesh, walkable map, camera path and a
metric grid, each a node under /scene that a GUI checkbox shows or hides; the scene card in the
GUI panel. Reads nothing from disk."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import viser

from vid2sim.viewer.card import metrics_table, scene_card
from vid2sim.viewer.layers import CameraPath, SceneLayers

MESH_RGB = (235, 120, 40)
MESH_OPACITY = 0.6  # the splats stay visible through the mesh
WALKABLE_RGBA = (60, 200, 90, 110)
PATH_RGB = (40, 110, 240)
GRID_CELL_M = 1.0  # one grid cell is one metre
GRID_SECTION_M = 5.0
MAX_FRUSTUMS = 24
LAYER_NAMES = ("splats", "collision mesh", "walkable map", "camera path", "grid (1 m cells)")


@dataclass
class SceneView:
    """Scene nodes and their GUI checkboxes by layer name (absent layers have neither)."""

    nodes: dict[str, list] = field(default_factory=dict)
    toggles: dict[str, viser.GuiCheckboxHandle] = field(default_factory=dict)
    gui: list = field(default_factory=list)

    def remove(self) -> None:
        for handles in self.nodes.values():
            for h in handles:
                h.remove()
        for h in [*self.toggles.values(), *self.gui]:
            h.remove()
        self.nodes.clear()
        self.toggles.clear()
        self.gui.clear()


def walkable_rgba(grid: np.ndarray) -> np.ndarray:
    """[H, W, 4] u8 image of a walkable grid: image row r is grid row r, since viser lays an image
    y-down (its row 0 on the plane's -y edge, where the grid's row 0, the lowest y, lies)."""
    img = np.zeros((*grid.shape, 4), np.uint8)
    img[grid > 0] = WALKABLE_RGBA
    return img


def _walkable(server: viser.ViserServer, layers: SceneLayers) -> list:
    w = layers.walkable
    lo, hi = w.origin, w.extent_max()
    centre = (float((lo[0] + hi[0]) / 2), float((lo[1] + hi[1]) / 2), 0.02)
    return [server.scene.add_image("/scene/walkable", walkable_rgba(w.grid), float(hi[0] - lo[0]),
                                   float(hi[1] - lo[1]), format="png", position=centre,
                                   cast_shadow=False, receive_shadow=False)]


def _camera_path(server: viser.ViserServer, cams: CameraPath) -> list:
    nodes = []
    if len(cams.centers) >= 2:
        nodes.append(server.scene.add_spline_catmull_rom("/scene/camera_path/line", cams.centers,
                                                         color=PATH_RGB, thickness=0.06))
    step = max(1, len(cams.centers) // MAX_FRUSTUMS)
    for i in range(0, len(cams.centers), step):
        wxyz = viser.transforms.SO3.from_matrix(cams.cam_to_world[i, :3, :3]).wxyz
        nodes.append(server.scene.add_camera_frustum(
            f"/scene/camera_path/frustum_{i}", fov=float(cams.fov_y[i]), aspect=float(cams.aspect[i]),
            scale=0.15, color=PATH_RGB, wxyz=wxyz, position=cams.centers[i]))
    return nodes


def _grid(server: viser.ViserServer, layers: SceneLayers) -> list:
    lo, hi = layers.bounds()
    size = np.ceil((hi[:2] - lo[:2]) / GRID_SECTION_M + 1) * GRID_SECTION_M
    centre = np.round((lo[:2] + hi[:2]) / 2 / GRID_SECTION_M) * GRID_SECTION_M
    grid = server.scene.add_grid("/scene/grid", width=float(size[0]), height=float(size[1]), plane="xy",
                                 cell_size=GRID_CELL_M, section_size=GRID_SECTION_M,
                                 position=(float(centre[0]), float(centre[1]), 0.0))
    label = server.scene.add_label("/scene/grid/scale", f"grid: {GRID_CELL_M:g} m cells, "
                                   f"{GRID_SECTION_M:g} m sections", position=(0.0, 0.0, 0.05))
    return [grid, label]


def draw_nodes(server: viser.ViserServer, layers: SceneLayers) -> dict[str, list]:
    """Add every present layer to the scene -> {layer name: node handles}."""
    nodes: dict[str, list] = {}
    s = layers.splats
    if s is not None:
        nodes["splats"] = [server.scene.add_gaussian_splats("/scene/splats", s.centers, s.covariances, s.rgbs,
                                                            s.opacities)]
    if layers.mesh is not None:
        m = layers.mesh
        nodes["collision mesh"] = [server.scene.add_mesh_simple(
            "/scene/collision_mesh", np.asarray(m.vertices, np.float32), np.asarray(m.faces, np.uint32),
            color=MESH_RGB, opacity=MESH_OPACITY, side="double", flat_shading=True)]
    if layers.walkable is not None:
        nodes["walkable map"] = _walkable(server, layers)
    if layers.cameras is not None:
        nodes["camera path"] = _camera_path(server, layers.cameras)
    nodes["grid (1 m cells)"] = _grid(server, layers)
    return nodes


def _toggle(box: viser.GuiCheckboxHandle, handles: list) -> None:
    @box.on_update
    def _(_event) -> None:
        for h in handles:
            h.visible = box.value


def look_from_above(server: viser.ViserServer, layers: SceneLayers) -> None:
    """Initial camera: above and behind the source video's first camera, looking down the walked
    path (without cameras: above the scene centre)."""
    lo, hi = layers.bounds(focus=True)
    centre = (lo + hi) / 2
    centre[2] = 0.0
    span = max(float(np.linalg.norm(hi[:2] - lo[:2])), 4.0)
    direction = np.array([0.45, 0.45])
    cams = layers.cameras
    if cams is not None and len(cams.centers) >= 2:
        walk = cams.centers[-1, :2] - cams.centers[0, :2]
        if np.linalg.norm(walk) > 0.5:
            direction = -walk / np.linalg.norm(walk) * 0.64
    server.initial_camera.look_at = tuple(centre)
    server.initial_camera.position = tuple(centre + np.append(direction, 0.45) * span)


def show_scene(server: viser.ViserServer, layers: SceneLayers, hidden: tuple[str, ...] = ()) -> SceneView:
    """Draw `layers` and add the Layers checkboxes and the scene card to the GUI."""
    view = SceneView(nodes=draw_nodes(server, layers))
    folder = server.gui.add_folder("Layers")
    view.gui.append(folder)
    with folder:
        for name in LAYER_NAMES:
            if name in view.nodes:
                box = server.gui.add_checkbox(name, initial_value=name not in hidden)
                _toggle(box, view.nodes[name])
                view.toggles[name] = box
                for h in view.nodes[name]:
                    h.visible = box.value
            else:
                view.gui.append(server.gui.add_markdown(f"*{name}: not in this bundle*"))
    card = server.gui.add_folder("Scene card")
    view.gui.append(card)
    with card:
        view.gui.append(server.gui.add_markdown(scene_card(layers.scene, layers.splats, layers.missing)))
    if layers.scene is not None and layers.scene.get("metrics"):
        metrics = server.gui.add_folder("All metrics", expand_by_default=False)
        view.gui.append(metrics)
        with metrics:
            view.gui.append(server.gui.add_markdown(metrics_table(layers.scene["metrics"])))
    look_from_above(server, layers)
    return view
