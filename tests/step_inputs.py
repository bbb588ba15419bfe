"""Small folders standing for the finished outputs of every step, each with a marker of a known
key, and the job they belong to: fixed inputs from which each step's cache key is computed
without running any stage (tests/test_step_runner.py checks the keys against recorded values)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import cv2
import numpy as np
import trimesh

from vid2sim.factory.ingest.clips import ClipSpec
from vid2sim.factory.ingest.sources import Source
from vid2sim.factory.runtime.config import ClipJob
from vid2sim.factory.runtime.stage_cache import mark_done
from vid2sim.factory.runtime.steps.base import CLIP, Step, StepOutputs
from vid2sim.factory.sfm.posed import PosedClip, PosedFrame
from vid2sim.splats.cpu.synthetic import street_scene
from vid2sim.splats.ply import write_ply

KEYS = {name: f"key-of-{name}" for name in ("decode", "masks", "sfm", "metric", "recon", "meshing", "walkable")}


def job(root: Path) -> ClipJob:
    source = Source("video", root / "v.mp4", "file:///v.mp4", "a" * 64)
    return ClipJob(ClipSpec("clip0", source, (0.0, 4.0), "g", tags={"city": "lund"}), "scene-1", "CC0")


def _posed_clip(folder: Path, images: Path) -> None:
    K = np.array([[50.0, 0, 32], [0, 50.0, 18], [0, 0, 1]])
    frames = []
    for i, x in enumerate(np.linspace(-1.0, 1.0, 5)):
        c2w = np.eye(4)
        c2w[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # looking along +x
        c2w[:3, 3] = (x, 0.0, 1.5)
        frames.append(PosedFrame(i, f"{i:06d}.jpg", i / 10, 64, 36, K, c2w))
    PosedClip(frames, images).save(folder)


def _files(root: Path) -> None:
    """The files each step's work reads before it decides whether to run."""
    (root / "decode" / "images").mkdir(parents=True)
    for i in range(2):
        cv2.imwrite(str(root / "decode" / "images" / f"{i:06d}.jpg"), np.full((36, 64, 3), 40 * i, np.uint8))
    (root / "masks" / "masks").mkdir(parents=True)
    (root / "sfm").mkdir()
    _posed_clip(root / "metric", root / "decode" / "images")
    (root / "recon").mkdir()
    write_ply(street_scene(50, length=4.0, seed=0), root / "recon" / "splats.ply")
    (root / "meshing").mkdir()
    x, y = np.meshgrid(np.arange(-2, 2, 0.1), np.arange(-1, 1, 0.1))
    np.save(root / "meshing" / "ground_points.npy", np.stack([x.ravel(), y.ravel(), 0 * x.ravel()], 1))
    trimesh.creation.box(extents=(0.5, 0.5, 0.5)).export(root / "meshing" / "collision.ply")
    (root / "walkable").mkdir()


def finished_outputs(root: Path, steps: tuple[Step, ...]) -> dict[str, StepOutputs]:
    """{step: its Outputs record} of folders under `root` marked done with the keys in KEYS."""
    _files(root)
    outputs = {}
    for step in steps:
        if step.name in KEYS:
            mark_done(root / step.name, step.name, KEYS[step.name], {}, 0.0)
            outputs[step.name] = step.outputs(root / step.name)
    return outputs


def step_inputs(step: Step, job: ClipJob, outputs: dict[str, StepOutputs]) -> object:
    """The step's Inputs record from `outputs` (the clip spec for `clip`)."""
    names = [f.name for f in fields(step.inputs)]
    return step.inputs(**{n: job.spec if n == CLIP else outputs[n] for n in names if n == CLIP or n in outputs})
