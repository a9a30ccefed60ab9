"""`CNEPConfig`: LeRobot's policy type `cnep`, a policy folder written by `cnep export`, evaluated as it is.

    lerobot-eval --policy.type=cnep --policy.policy_dir=policy/ --env.type=cnep --env.task=Obstacle-v0 \
        --eval.batch_size=1 --eval.n_episodes=10

The folder is closed (cnep.runtime.manifest: nothing in it but what its manifest lists), so it carries no LeRobot
`config.json`: the policy is named by its type and folder, not by --policy.path. It is trained with `cnep train`
and exported with `cnep export`; LeRobot's training presets are refused.
"""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType

from cnep.runtime.errors import PolicyError

TYPE = "cnep"  # the policy type, as --policy.type names it
NOT_TRAINED_HERE = "a cnep policy is trained with `cnep train` and exported with `cnep export`, not by lerobot-train"


@PreTrainedConfig.register_subclass(TYPE)
@dataclass
class CNEPConfig(PreTrainedConfig):
    """policy_dir: the folder `cnep export` wrote; threads: intra-op threads of its graphs (one, as the project's
    closed loop steps them, one frame at a time)."""

    policy_dir: str | None = None
    threads: int = 1

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.threads < 1:
            raise PolicyError(f"--policy.threads is the graphs' intra-op threads, >= 1; got {self.threads}")

    @property
    def observation_delta_indices(self) -> None:
        return None  # the current observation only: the policy keeps its own conditioning set

    @property
    def action_delta_indices(self) -> None:
        return None

    @property
    def reward_delta_indices(self) -> None:
        return None

    def get_optimizer_preset(self) -> None:
        raise PolicyError(NOT_TRAINED_HERE)

    def get_scheduler_preset(self) -> None:
        raise PolicyError(NOT_TRAINED_HERE)

    def validate_features(self) -> None:
        if not any(ft.type is FeatureType.STATE for ft in (self.input_features or {}).values()):
            raise PolicyError("a cnep policy reads the robot's state: the inputs need observation.state")
