"""`CnepEnv`: LeRobot's env type `cnep`, the cnep simulator's tasks (cnep.sim) in lerobot-eval.

    --env.type=cnep --env.task=Obstacle-v0        # any cnep/<task> environment: Obstacle-v1, ObstacleCue-v0, ...
    --env.type=cnep --env.task=PickPlace-v0 --env.condition=free

lerobot-eval makes its environment with gym.make(EnvConfig.gym_id). For every `cnep/<task>` environment this module
registers `cnep_lerobot/<task>`: the same environment observed under LeRobot's gym keys (adapter.gym_observation),
rendering the frame it last observed (lerobot-eval writes its first episodes as videos), its episode's control
steps as the `_max_episode_steps` lerobot-eval reads.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION

from cnep.sim import scene
from lerobot_policy_cnep.adapter import PIXELS, gym_observation, policy_features

SIM_NAMESPACE, NAMESPACE = "cnep", "cnep_lerobot"  # cnep.sim's environments, and them under LeRobot's keys
TYPE = "cnep"  # the env type, as --env.type names it


class LerobotKeys(gym.ObservationWrapper):
    """A cnep.sim environment observed under LeRobot's gym keys (module docstring)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        spaces = gym_observation(env.observation_space.spaces)
        self.observation_space = gym.spaces.Dict(
            {key: gym.spaces.Dict(value) if isinstance(value, dict) else value for key, value in spaces.items()}
        )
        self._max_episode_steps = env.unwrapped.max_steps  # what lerobot-eval's rollout runs at most
        self._frame = None

    def observation(self, observation: dict) -> dict:
        mapped = gym_observation(observation)
        self._frame = next(iter(mapped[PIXELS].values())) if PIXELS in mapped else None
        return mapped

    def render(self):
        """The camera's frame (H, W, 3) uint8 the policy saw last, None for an environment without a camera."""
        return self._frame


def make_env(task: str, **kwargs) -> LerobotKeys:
    """The environment `cnep/<task>` made with `kwargs`, under LeRobot's keys."""
    return LerobotKeys(gym.make(f"{SIM_NAMESPACE}/{task}", disable_env_checker=True, **kwargs))


def register_envs() -> None:
    """`cnep_lerobot/<task>` registered for every `cnep/<task>` environment (cnep.sim registers those on import)."""
    for env_id in [i for i in gym.registry if i.startswith(f"{SIM_NAMESPACE}/")]:
        task = env_id.removeprefix(f"{SIM_NAMESPACE}/")
        gym.register(id=f"{NAMESPACE}/{task}", entry_point=make_env, kwargs={"task": task})


@EnvConfig.register_subclass(TYPE)
@dataclass
class CnepEnv(EnvConfig):
    """task: the cnep.sim environment `cnep/<task>`; episode_length: its control steps (None: the environment's own);
    condition: the pick-and-place scene's condition (decided, free, changed; None: the environment's mix)."""

    task: str | None = "Obstacle-v0"
    fps: int = round(1 / scene.CONTROL_PERIOD_S)
    episode_length: int | None = None
    condition: str | None = None

    def __post_init__(self) -> None:
        env = gym.make(self.gym_id, **self.gym_kwargs)
        try:
            shapes = {key: space.shape for key, space in env.unwrapped.observation_space.spaces.items()}
            self.features = {ACTION: PolicyFeature(type=FeatureType.ACTION, shape=env.action_space.shape)}
        finally:
            env.close()
        self.features_map = {ACTION: ACTION}
        for key, (policy_key, kind, shape) in policy_features(shapes).items():
            self.features[key] = PolicyFeature(type=FeatureType[kind], shape=shape)
            self.features_map[key] = policy_key

    @property
    def package_name(self) -> str:
        return __name__.split(".")[0]  # imported before lerobot-eval makes the environment: its ids registered

    @property
    def gym_id(self) -> str:
        return f"{NAMESPACE}/{self.task}"

    @property
    def gym_kwargs(self) -> dict:
        given = {"max_steps": self.episode_length, "condition": self.condition}
        return {key: value for key, value in given.items() if value is not None}
