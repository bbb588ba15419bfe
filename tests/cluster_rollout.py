"""A short distributed training job for the 2-node cluster test.

`distill_rounds`: the training package's `RayVecEnv` with one env actor per node (SPREAD) steps
`vid2sim/PointNav-v0` on the scene the cluster just committed (each actor checks it out of the
object-store registry on its own node), the scripted teacher labels every state, and the driver
runs a few DAgger rounds of the pixel student (collection on both nodes, learner updates in the
driver). `RolloutWorker`s (one per node) check the scene out too, write their stats into the
run folder on the store and tag the scene in the registry (commits from worker nodes,
concurrently); the driver writes the run's marker last.
"""

from __future__ import annotations

import json
import os

from pathlib import Path

import numpy as np
import ray
import torch

from vid2sim.envs.config import EpisodeConfig
from vid2sim.factory.runtime.object_store import ObjectStore
from vid2sim.factory.runtime.staging import scratch_root
from vid2sim.formats.walkable import load_walkable
from vid2sim.registry import Registry
from vid2sim.training.config import DistillConfig, TrainConfig
from vid2sim.training.distill import Collector, Dataset, env_specs, fit, make_student
from vid2sim.training.rollouts import RayVecEnv, RayVecEnvConfig
from vid2sim.training.student import StudentConfig


@ray.remote(num_cpus=0.5)
class RolloutWorker:
    """Checks the scene out on its node, reports where it runs, writes stats and tags the scene."""

    def __init__(self, registry_uri: str, scene_id: str) -> None:
        dest = scratch_root() / "checkouts" / scene_id
        bundle = Registry(registry_uri).checkout(scene_id, dest=dest)
        self.walkable_cells = int(load_walkable(bundle / "walkable.npz").grid.sum())

    def where(self) -> dict:
        return {"node_id": ray.get_runtime_context().get_node_id(),
                "scratch": os.environ.get("VID2SIM_SCRATCH", ""), "walkable_cells": self.walkable_cells}

    def report(self, work_uri: str, run_key: str, registry_uri: str, scene_id: str, stats: dict) -> dict:
        """From this node: write the worker's stats into the run folder and tag the scene in the
        registry (the workers commit concurrently to the same scene)."""
        info = {**self.where(), **stats}
        name = info["node_id"][:12]
        ObjectStore(work_uri).write_bytes(f"{run_key}/workers/{name}.json", json.dumps(info).encode())
        info["tag_version"] = Registry(registry_uri).tag(scene_id, f"rollout-{name}").version
        return info


def distill_rounds(registry_uri: str, scene_id: str, run_dir: Path, rounds: int = 3) -> dict:
    """A few DAgger rounds with env actors on both nodes; the nodes, labels and learner losses."""
    small = StudentConfig(channels=(4, 8, 8, 8), frame_dim=16, vector_dim=8, hidden=32)
    config = TrainConfig(run_dir=str(run_dir), total_steps=rounds * 60, registry=registry_uri, scene_ids=[scene_id],
                         n_envs=2, n_actors=2, method="distill", stuck_steps=10,
                         env_kwargs={"training": True, "fidelity": "exact", "checkout_root": None,
                                     # the 2-s clip's walk is ~2.8 m: shorter episodes than the paper's 10-30 m
                                     "episode": EpisodeConfig(geodesic_range=(1.0, 2.5), min_geodesic=1.0)},
                         distill=DistillConfig(steps_per_round=60, updates_per_round=20, batch_size=16,
                                               train_max_steps=40, student=small))
    env = RayVecEnv(env_specs(config), RayVecEnvConfig(n_actors=2, num_cpus_per_actor=0.5,
                                                       scheduling_strategy="SPREAD"))
    try:
        nodes = env.actor_nodes()
        student = make_student(config, env)
        optimizer = torch.optim.Adam(student.parameters(), lr=1e-3)
        collector, dataset, rng = Collector(env, student, 0), Dataset(10_000), np.random.default_rng(0)
        labels, losses = [], []
        for k in range(rounds):
            batch, stats = collector.collect(60, 0.5 ** k, True)
            dataset.add(batch)
            losses.append(fit(student, optimizer, dataset.arrays(), 20, 16, 2, rng)["loss"])
            labels.append(stats.labels)
    finally:
        env.close()
    return {"env_nodes": nodes, "labels": labels, "losses": losses}
