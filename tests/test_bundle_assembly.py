"""Manifest tags become valid registry tags (free text such as licences has spaces)."""

from __future__ import annotations

from vid2sim.factory.runtime.steps.bundle import tag
from vid2sim.formats.scene import make_scene_json


def test_free_text_tags_are_made_valid_for_the_registry():
    tags = [tag("licence", "Apache-2.0 OR MIT"), tag("city", "São Paulo"), tag("weather", "light rain")]
    assert tags == ["licence:Apache-2.0-OR-MIT", "city:S-o-Paulo", "weather:light-rain"]
    scene = make_scene_json("s-1", source_uri="file:///v.mp4", source_sha256="a" * 64, clip_start_s=0,
                            clip_end_s=10, scale_source="capture_height", tags=tags)
    assert scene["tags"] == tags
