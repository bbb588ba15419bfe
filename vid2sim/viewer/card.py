"""The scene card: source, licence, world frame, corridor figures and metrics as Markdown.

Reads the scene.json dict (and the layer summary); writes nothing.
"""

from __future__ import annotations

from typing import Any, Optional

from vid2sim.viewer.splats import SplatLayer

CORRIDOR_PREFIX = "corridor."
HEADLINE = ("recon.psnr", "recon.ssim", "recon.n_gaussians", "sfm.registered_fraction", "sfm.mean_reproj_error_px",
            "walkable.walkable_area_m2", "walkable.collision_faces", "psnr", "walkable_area_m2", "path_length_m")


def licence_of(scene: dict) -> str:
    """The licence recorded in source.license or a `licence:` tag ('unknown' when neither)."""
    lic = scene.get("source", {}).get("license")
    tags = [t.split(":", 1)[1] for t in scene.get("tags", []) if t.startswith(("licence:", "license:"))]
    return lic or (tags[0] if tags else "unknown")


def _fmt(v: Any) -> str:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return str(v)
    return f"{v:,}" if isinstance(v, int) else f"{v:.4g}"


def _table(rows: list[tuple[str, Any]]) -> str:
    return "\n".join(["| | |", "|---|---|"] + [f"| {k} | {_fmt(v)} |" for k, v in rows])


def metrics_groups(metrics: dict) -> tuple[list[tuple[str, Any]], list[tuple[str, Any]]]:
    """(corridor figures, other metrics) as sorted (name, value) rows."""
    scalars = sorted((k, v) for k, v in metrics.items() if isinstance(v, (int, float, str, bool)))
    return ([(k[len(CORRIDOR_PREFIX):], v) for k, v in scalars if k.startswith(CORRIDOR_PREFIX)],
            [(k, v) for k, v in scalars if not k.startswith(CORRIDOR_PREFIX)])


def scene_card(scene: Optional[dict], splats: Optional[SplatLayer], missing: dict[str, str]) -> str:
    """Markdown of the scene card."""
    parts = []
    if missing:
        parts.append("**Missing layers**: " + "; ".join(f"`{n}` ({why})" for n, why in missing.items()))
    if splats is not None:
        parts.append(f"**Splats shown**: {splats.shown:,} of {splats.total:,}")
    if scene is None:
        return "\n\n".join(parts + ["No scene.json: source, licence and metrics unknown."])
    src, wf = scene["source"], scene["world_frame"]
    parts.append(_table([("scene", scene["scene_id"]), ("source", src["uri"]),
                         ("clip", f"{src['clip_start_s']:.1f}-{src['clip_end_s']:.1f} s"),
                         ("licence", licence_of(scene)), ("scale from", wf["scale_source"]),
                         ("tags", ", ".join(scene.get("tags", [])) or "-")]))
    corridor, other = metrics_groups(scene.get("metrics", {}))
    if corridor:
        parts.append("**Walked corridor**\n\n" + _table(corridor))
    headline = [(k, v) for k, v in other if k in HEADLINE]
    if headline:
        parts.append("**Headline metrics**\n\n" + _table(headline))
    return "\n\n".join(parts)


def metrics_table(metrics: dict) -> str:
    """Every scalar metric, corridor figures included, as one Markdown table."""
    corridor, other = metrics_groups(metrics)
    return _table([(CORRIDOR_PREFIX + k, v) for k, v in corridor] + other)
