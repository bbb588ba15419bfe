"""Gymnasium navigation environments on registry scenes.

`gymnasium.make("vid2sim/PointNav-v0", registry=ROOT, scenes=SCENE_ID_OR_LIST_OR_"split:NAME")`
and `vid2sim/SocialNav-v0` (pedestrians). The contract is in `vid2sim.envs.nav_env`.
"""

import gymnasium

from vid2sim.envs.config import EnvConfig

ENV_IDS = ("vid2sim/PointNav-v0", "vid2sim/SocialNav-v0")


def _register() -> None:
    for env_id, task in zip(ENV_IDS, ("pointnav", "socialnav")):
        if env_id not in gymnasium.registry:
            # no PassiveEnvChecker: it counts a first reset() that raised (a scene with no free
            # start) as checked and then fails the first step() of every later episode with a
            # TypeError; NavEnv enforces reset-before-step itself and tests run the full check_env
            gymnasium.register(env_id, entry_point="vid2sim.envs.nav_env:NavEnv",
                               kwargs={"task": task}, disable_env_checker=True)


_register()

__all__ = ["EnvConfig", "ENV_IDS"]
