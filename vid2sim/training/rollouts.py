"""Parallel rollouts on Ray actors, exposed to stable-baselines3 as a `VecEnv`.

Each `EnvWorker` actor hosts several environments and steps them all in one call (an actor
call costs about 1 ms, so batching per actor matters more than the number of actors). The
`RayVecEnv` keeps SB3's contract exactly (same as `DummyVecEnv`): on the step where an episode
ends, `done` is True, `info["terminal_observation"]` holds the last observation,
`info["TimeLimit.truncated"]` is `truncated and not terminated`, and the returned observation is
already the first observation of the next episode (same-step auto-reset; Gymnasium 1.x vector
envs default to next-step auto-reset instead, which SB3 does not expect).

Fault tolerance: when an actor dies (node loss, OOM kill), it is re-created with the same env
specs, its environments are reset, and the interrupted step is reported for those envs as a
truncation (`done=True`, `TimeLimit.truncated=True`, reward 0, `terminal_observation` = their last
observation, `info["actor_restarted"]=True`), so off-policy learners bootstrap it like a time-out.
Settings made through the vec env survive the replacement: every `set_attr` and every `env_method`
call of a method named `set_*` (e.g. `NavEnv.set_scene_weights`) is remembered per env, the latest
per name, and replayed on the new actor's envs before they reset.
"""

from __future__ import annotations

import importlib
import os
from dataclasses import asdict, dataclass, field
from typing import Any, Iterable, Optional, Sequence

import gymnasium as gym
import numpy as np
import ray
from ray.exceptions import RayActorError
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvStepReturn

from vid2sim.factory.runtime.orchestrator import init_ray  # noqa: F401  (the one Ray start, re-exported)
from vid2sim.ranges import checked
from vid2sim.training.actions import ActionMapping
from vid2sim.training.wrappers import ExpertActions, StuckTermination, TeacherLabels


@dataclass
class EnvSpec:
    """How to build one environment in any process: `import module; gym.make(env_id, **kwargs)`."""

    env_id: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    seed: Optional[int] = None
    module: Optional[str] = None  # imported first, so the env id is registered (e.g. "vid2sim.envs")
    stuck_steps: Optional[int] = None  # training only: `StuckTermination` after this many blocked steps
    expert: bool = False  # wrap in `ExpertActions` (env_method("expert_action"), needs a NavEnv)
    action_map: str = "clamp"  # outermost `ActionMapping` unless "clamp" (the envs' own contract)
    teacher: bool = False  # wrap in `TeacherLabels` (the expert's label of every state in the infos)
    teacher_clearance_rays: int = 0  # with teacher: also its privileged clearance over the view, this many rays
    teacher_depth_grid: Optional[tuple[int, int]] = None  # with teacher: also the frame's depth in h x w blocks
    teacher_replan: float = 0.0  # with teacher: m off its path at which it re-plans (0: every state)
    teacher_lookahead: float = 1.0  # with teacher: m ahead on its path its pure pursuit aims
    teacher_waypoints: int = 0  # with teacher: also its route ahead as this many points

    def make(self) -> gym.Env:
        if self.module:
            importlib.import_module(self.module)
        env = gym.make(self.env_id, **self.kwargs)
        env = (TeacherLabels(env, self.teacher_replan, self.teacher_clearance_rays, self.teacher_depth_grid,
                             self.teacher_lookahead, self.teacher_waypoints)
               if self.teacher else env)
        env = ExpertActions(env) if self.expert else env
        env = StuckTermination(env, self.stuck_steps) if self.stuck_steps else env
        return ActionMapping(env, self.action_map) if self.action_map != "clamp" else env

    def to_dict(self) -> dict:
        return asdict(self)


def specs_for_scenes(env_id: str, scene_ids: Sequence[str], n_envs: int, base_kwargs: dict[str, Any],
                     seed: int = 0, module: Optional[str] = "vid2sim.envs",
                     scene_key: str = "scenes", stuck_steps: Optional[int] = None,
                     expert: bool = False, action_map: str = "clamp", teacher: bool = False) -> list[EnvSpec]:
    """`n_envs` specs with the scenes of a registry split dealt round-robin (env i gets scene i % S)."""
    if not scene_ids:
        raise ValueError("no scenes given")
    return [EnvSpec(env_id, {**base_kwargs, scene_key: scene_ids[i % len(scene_ids)]}, seed + i, module,
                    stuck_steps, expert, action_map, teacher)
            for i in range(n_envs)]


def partition(n_items: int, n_parts: int) -> list[list[int]]:
    """Contiguous, balanced blocks of item indices (block sizes differ by at most one)."""
    n_parts = max(1, min(n_parts, n_items))
    size, extra = divmod(n_items, n_parts)
    blocks, start = [], 0
    for k in range(n_parts):
        stop = start + size + (k < extra)
        blocks.append(list(range(start, stop)))
        start = stop
    return blocks


def stack_obs(obs_list: Sequence[Any], space: gym.Space) -> Any:
    """Stack per-env observations into fresh, writeable arrays (ray.get gives read-only views)."""
    if isinstance(space, gym.spaces.Dict):
        return {k: np.stack([np.array(o[k], copy=True) for o in obs_list]) for k in space.spaces}
    return np.stack([np.array(o, copy=True) for o in obs_list])


def copy_obs(obs: Any) -> Any:
    """A writeable deep copy of one (possibly Dict) observation."""
    if isinstance(obs, dict):
        return {k: np.array(v, copy=True) for k, v in obs.items()}
    return np.array(obs, copy=True)


class EnvWorker:
    """Hosts several environments in one process; every method handles all of them in one call."""

    def __init__(self, specs: Sequence[EnvSpec]):
        self.specs = list(specs)
        self.envs = [s.make() for s in self.specs]

    def pid(self) -> int:
        return os.getpid()

    def node_id(self) -> str:
        """The Ray node this worker runs on ("" outside Ray)."""
        return ray.get_runtime_context().get_node_id() if ray.is_initialized() else ""

    def spaces(self) -> tuple[gym.Space, gym.Space]:
        return self.envs[0].observation_space, self.envs[0].action_space

    def reset(self, seeds: Sequence[Optional[int]], options: Sequence[dict]) -> list[tuple[Any, dict]]:
        out = []
        for env, seed, opt in zip(self.envs, seeds, options):
            out.append(env.reset(seed=seed, **({"options": opt} if opt else {})))
        return out

    def step(self, actions: np.ndarray) -> list[tuple[Any, float, bool, dict, dict]]:
        """Step every env; same-step auto-reset exactly as SB3's DummyVecEnv."""
        out = []
        for env, action in zip(self.envs, actions):
            obs, reward, terminated, truncated, info = env.step(action)
            done = bool(terminated or truncated)
            info = dict(info)
            info["TimeLimit.truncated"] = bool(truncated and not terminated)
            reset_info: dict = {}
            if done:
                info["terminal_observation"] = obs
                obs, reset_info = env.reset()
            out.append((obs, float(reward), done, info, reset_info))
        return out

    def call(self, local_idx: Sequence[int], name: str, args: tuple, kwargs: dict) -> list[Any]:
        return [self.envs[i].get_wrapper_attr(name)(*args, **kwargs) for i in local_idx]

    def get_attr(self, local_idx: Sequence[int], name: str) -> list[Any]:
        return [self.envs[i].get_wrapper_attr(name) for i in local_idx]

    def set_attr(self, local_idx: Sequence[int], name: str, value: Any) -> None:
        for i in local_idx:
            self.envs[i].set_wrapper_attr(name, value)

    def is_wrapped(self, local_idx: Sequence[int], wrapper_class: type) -> list[bool]:
        return [is_wrapped(self.envs[i], wrapper_class) for i in local_idx]

    def render(self) -> list[Optional[np.ndarray]]:
        return [env.render() for env in self.envs]

    def close(self) -> None:
        for env in self.envs:
            env.close()


@checked
@dataclass
class RayVecEnvConfig:
    n_actors: int = 2
    num_cpus_per_actor: float = 1.0
    max_restarts: int = 10  # per RayVecEnv, across actors; then the error propagates
    scheduling_strategy: Optional[str] = None  # Ray's: None (default packing) or "SPREAD" (one actor per node first)


class RayVecEnv(VecEnv):
    """SB3 `VecEnv` over Ray actors that each host a contiguous block of the env specs."""

    def __init__(self, specs: Sequence[EnvSpec], config: RayVecEnvConfig = RayVecEnvConfig()):
        if not ray.is_initialized():
            raise RuntimeError("ray.init(...) first (embedded local runtime or a cluster address)")
        self.specs = list(specs)
        self.config = config
        self.blocks = partition(len(self.specs), config.n_actors)
        self._actor_cls = ray.remote(num_cpus=config.num_cpus_per_actor)(EnvWorker)
        self.actors = [self._new_actor(b) for b in self.blocks]
        self.restarts = 0
        obs_space, act_space = ray.get(self.actors[0].spaces.remote())
        super().__init__(len(self.specs), obs_space, act_space)
        self._seeds = [s.seed for s in self.specs]
        self._last_obs: list[Any] = [None] * self.num_envs
        self._actions: Optional[np.ndarray] = None
        # per env: the settings to replay on a replaced actor, {(kind, name): payload}, the latest per name
        self._settings: list[dict[tuple[str, str], Any]] = [{} for _ in self.specs]

    def _new_actor(self, block: Sequence[int]) -> Any:
        cls = self._actor_cls
        if self.config.scheduling_strategy:
            cls = cls.options(scheduling_strategy=self.config.scheduling_strategy)
        return cls.remote([self.specs[i] for i in block])

    # ---------------------------------------------------------------- core API
    def reset(self) -> Any:
        futures = [a.reset.remote([self._seeds[i] for i in b], [self._options[i] for i in b])
                   for a, b in zip(self.actors, self.blocks)]
        for k, fut in enumerate(futures):
            try:
                results = ray.get(fut)
            except RayActorError:
                results = self._restart(k)
            self._store_reset(self.blocks[k], results)
        self._reset_seeds()
        self._reset_options()
        return stack_obs(self._last_obs, self.observation_space)

    def _store_reset(self, block: Sequence[int], results: Sequence[tuple[Any, dict]]) -> None:
        for i, (obs, info) in zip(block, results):
            self._last_obs[i] = copy_obs(obs)
            self.reset_infos[i] = dict(info)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        assert self._actions is not None, "step_async first"
        futures = [a.step.remote(self._actions[b]) for a, b in zip(self.actors, self.blocks)]
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        for k, fut in enumerate(futures):
            try:
                results = ray.get(fut)
            except RayActorError:
                results = self._restarted_step(k)
            for i, (obs, rew, done, info, reset_info) in zip(self.blocks[k], results):
                if "terminal_observation" in info:
                    info["terminal_observation"] = copy_obs(info["terminal_observation"])
                self._last_obs[i], rewards[i], dones[i], infos[i] = copy_obs(obs), rew, done, info
                if done:
                    self.reset_infos[i] = reset_info
        self._actions = None
        return stack_obs(self._last_obs, self.observation_space), rewards, dones, infos

    # ---------------------------------------------------------------- fault tolerance
    def _restart(self, k: int) -> list[tuple[Any, dict]]:
        """Re-create actor k with the same specs and reset its envs (fresh seeds derived from the specs)."""
        if self.restarts >= self.config.max_restarts:
            raise RuntimeError(f"Ray env actor {k} died and the restart budget ({self.config.max_restarts}) is spent")
        self.restarts += 1
        self.actors[k] = self._new_actor(self.blocks[k])
        self._replay_settings(k)
        seeds = [None if self.specs[i].seed is None else self.specs[i].seed + 100_003 * self.restarts
                 for i in self.blocks[k]]
        return ray.get(self.actors[k].reset.remote(seeds, [{} for _ in self.blocks[k]]))

    def _restarted_step(self, k: int) -> list[tuple[Any, float, bool, dict, dict]]:
        """The interrupted step of a dead actor's envs, reported as a truncation (see module docs)."""
        last = [self._last_obs[i] for i in self.blocks[k]]
        out = []
        for prev, (obs, reset_info) in zip(last, self._restart(k)):
            info = {"terminal_observation": prev, "TimeLimit.truncated": True, "actor_restarted": True}
            out.append((obs, 0.0, True, info, reset_info))
        return out

    def _remember(self, indices: VecEnvIndices, key: tuple[str, str], payload: Any) -> None:
        for i in self._get_indices(indices):
            self._settings[i][key] = payload

    def _replay_settings(self, k: int) -> None:
        """Apply the remembered settings of block k's envs to its (new) actor."""
        calls = []
        for local, i in enumerate(self.blocks[k]):
            for (kind, name), payload in self._settings[i].items():
                if kind == "attr":
                    calls.append(self.actors[k].set_attr.remote([local], name, payload))
                else:
                    args, kwargs = payload
                    calls.append(self.actors[k].call.remote([local], name, args, kwargs))
        ray.get(calls)

    def actor_pids(self) -> list[int]:
        return ray.get([a.pid.remote() for a in self.actors])

    def actor_nodes(self) -> list[str]:
        return ray.get([a.node_id.remote() for a in self.actors])

    # ---------------------------------------------------------------- attribute / method access
    def _by_actor(self, indices: VecEnvIndices) -> Iterable[tuple[int, list[int], list[int]]]:
        wanted = set(self._get_indices(indices))
        for k, block in enumerate(self.blocks):
            glob = [i for i in block if i in wanted]
            if glob:
                yield k, glob, [block.index(i) for i in glob]

    def _gather(self, indices: VecEnvIndices, call) -> list[Any]:
        order, futures = [], []
        for k, glob, local in self._by_actor(indices):
            order.extend(glob)
            futures.append(call(self.actors[k], local))
        values = [v for chunk in ray.get(futures) for v in chunk]
        by_index = dict(zip(order, values))
        return [by_index[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._gather(indices, lambda a, loc: a.get_attr.remote(loc, attr_name))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._remember(indices, ("attr", attr_name), value)
        ray.get([self.actors[k].set_attr.remote(loc, attr_name, value) for k, _, loc in self._by_actor(indices)])

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        if method_name.startswith("set_"):
            self._remember(indices, ("call", method_name), (method_args, method_kwargs))
        return self._gather(indices, lambda a, loc: a.call.remote(loc, method_name, method_args, method_kwargs))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._gather(indices, lambda a, loc: a.is_wrapped.remote(loc, wrapper_class))

    def get_images(self) -> Sequence[Optional[np.ndarray]]:
        return [img for chunk in ray.get([a.render.remote() for a in self.actors]) for img in chunk]

    def close(self) -> None:
        for a in self.actors:
            try:
                ray.get(a.close.remote())
            except RayActorError:
                pass
            ray.kill(a)
        self.actors = []
