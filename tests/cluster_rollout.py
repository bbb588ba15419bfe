"""A short distributed rollout/training job for the 2-node cluster test.

It uses plain Ray actors (not the training package, so it tests distribution alone) stepping a real
Gymnasium env (CartPole-v1) and trains a linear policy by random search (the driver keeps the
best perturbation each round). Each actor first checks the committed scene out of the registry
on its own node (object store, nothing shared) and reads its walkable map, so the job proves the
registry is readable from every node; each actor writes its own stats into the run folder on the
store and tags the scene in the registry (commits from worker nodes, concurrently); the driver
writes the run's marker last.
"""

from __future__ import annotations

import json
import os

import gymnasium as gym
import numpy as np
import ray

from vid2sim.factory.runtime.object_store import ObjectStore
from vid2sim.factory.runtime.staging import scratch_root
from vid2sim.formats.walkable import load_walkable
from vid2sim.registry import Registry


@ray.remote(num_cpus=1)
class RolloutWorker:
    """Steps CartPole with linear policies; reports where it runs and the scene it read."""

    def __init__(self, registry_uri: str, scene_id: str, seed: int) -> None:
        dest = scratch_root() / "checkouts" / scene_id
        bundle = Registry(registry_uri).checkout(scene_id, dest=dest)
        grid = load_walkable(bundle / "walkable.npz")
        self.walkable_cells = int(grid.grid.sum())
        self.env = gym.make("CartPole-v1")
        self.seed = seed
        self.steps = 0

    def where(self) -> dict:
        return {"node_id": ray.get_runtime_context().get_node_id(),
                "scratch": os.environ.get("VID2SIM_SCRATCH", ""), "walkable_cells": self.walkable_cells}

    def evaluate(self, weights: np.ndarray, episodes: int = 2) -> float:
        """Mean return of the policy `action = [obs, 1] . weights > 0`."""
        total = 0.0
        for e in range(episodes):
            obs, _ = self.env.reset(seed=self.seed * 1000 + e)
            done = False
            while not done:
                action = int(np.dot(np.append(obs, 1.0), weights) > 0)
                obs, reward, term, trunc, _ = self.env.step(action)
                total += float(reward)
                self.steps += 1
                done = term or trunc
        return total / episodes

    def report(self, work_uri: str, run_key: str, registry_uri: str, scene_id: str) -> dict:
        """From this node: write the worker's stats into the run folder and tag the scene in the
        registry (the workers commit concurrently to the same scene)."""
        info = {**self.where(), "env_steps": self.steps}
        name = info["node_id"][:12]
        ObjectStore(work_uri).write_bytes(f"{run_key}/workers/{name}.json", json.dumps(info).encode())
        info["tag_version"] = Registry(registry_uri).tag(scene_id, f"rollout-{name}").version
        return info


def train(workers: list, rounds: int, rng: np.random.Generator, sigma: float = 0.5) -> list[float]:
    """Random search: every worker scores one perturbation per round; keep the best."""
    weights = np.zeros(5)
    best = ray.get(workers[0].evaluate.remote(weights))
    curve = [best]
    for _ in range(rounds):
        cands = [weights + sigma * rng.standard_normal(5) for _ in workers]
        scores = ray.get([w.evaluate.remote(c) for w, c in zip(workers, cands)])
        i = int(np.argmax(scores))
        if scores[i] > best:
            weights, best = cands[i], scores[i]
        curve.append(best)
    return curve
