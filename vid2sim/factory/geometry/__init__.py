"""Geometry stages: collision and visual meshes, walkable map, ray casting, splat depth views."""
