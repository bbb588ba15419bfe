"""The registry page: every active scene of a registry with its preview, tags, split (seed 0)
and metrics, each with an Open button that shows the scene in the viewer.

Reads the manifest and each scene's preview.png blob; Open checks the scene out
(`vid2sim.viewer.source`).
"""

from __future__ import annotations

from typing import Callable, Optional

import cv2
import numpy as np
import viser

from vid2sim.formats.bundle import PREVIEW_PNG
from vid2sim.registry import Registry
from vid2sim.registry.records import SceneRecord

PREVIEW_WIDTH = 320  # px
CARD_METRICS = ("recon.psnr", "recon.ssim", "sfm.registered_fraction", "corridor.walkable_fraction")


def preview_image(reg: Registry, rec: SceneRecord) -> Optional[np.ndarray]:
    """The scene's preview.png as RGB, PREVIEW_WIDTH px wide (None when it has none)."""
    art = next((a for a in rec.artifacts if a.name == PREVIEW_PNG), None)
    if art is None:
        return None
    with reg.blobs.open(art.sha256) as f:
        bgr = cv2.imdecode(np.frombuffer(f.read(), np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        return None
    h = max(1, round(bgr.shape[0] * PREVIEW_WIDTH / bgr.shape[1]))
    return np.ascontiguousarray(cv2.resize(bgr, (PREVIEW_WIDTH, h), interpolation=cv2.INTER_AREA)[:, :, ::-1])


def split_of(reg: Registry) -> dict[str, str]:
    """scene id -> 'train' | 'test' in the seed-0 split ('-' when the registry cannot be split)."""
    try:
        split = reg.split(seed=0)
    except Exception:  # too few scenes or groups for a split: no split to show
        return {}
    return {**{s: "train" for s in split.train}, **{s: "test" for s in split.test}}


def scene_summary(rec: SceneRecord, split: str) -> str:
    """Markdown lines of one scene's entry."""
    metrics = [f"{k} {rec.metrics[k]:.3g}" for k in CARD_METRICS if isinstance(rec.metrics.get(k), (int, float))]
    return "\n\n".join([
        f"**{rec.ref}** · split: **{split}** · {rec.num_frames} frames · {rec.num_splats:,} splats · "
        f"walkable {rec.walkable_area_m2:.1f} m²",
        "tags: " + (", ".join(f"`{t}`" for t in rec.tags) or "-"),
        *([" · ".join(metrics)] if metrics else [])])


def show_registry(server: viser.ViserServer, reg: Registry, open_scene: Callable[[str], None]) -> list:
    """Add the Registry folder to the GUI; `open_scene(scene_id)` runs on a scene's Open button."""
    records = reg.list()
    splits = split_of(reg)
    handles = [server.gui.add_folder(f"Registry: {len(records)} scenes", order=-2)]
    with handles[0]:
        if not records:
            handles.append(server.gui.add_markdown(f"*no scenes in {reg.root}*"))
        for rec in records:
            img = preview_image(reg, rec)
            if img is not None:
                handles.append(server.gui.add_image(img, label=rec.scene_id))
            handles.append(server.gui.add_markdown(scene_summary(rec, splits.get(rec.scene_id, "-"))))
            button = server.gui.add_button(f"Open {rec.scene_id}")
            button.on_click(lambda _e, sid=rec.scene_id: open_scene(sid))
            handles.append(button)
    return handles
