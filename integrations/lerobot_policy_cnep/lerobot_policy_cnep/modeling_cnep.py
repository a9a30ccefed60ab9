"""`CNEPPolicy`: an exported CNEP (cnep.runtime.load_policy, no torch inside) as LeRobot's PreTrainedPolicy.

LeRobot hands a batch of tensors (lerobot.envs.utils.preprocess_observation: cameras (1, 3, H, W) float in [0, 1],
the state (1, 8)); the runtime's policy reads them as numpy arrays and gives the next waypoint of its own columns,
which the state fills out to the environment's (1, 8) action (lerobot_policy_cnep.adapter). The module holds no
parameters: the ONNX graphs run on the CPU whatever --policy.device says.
"""

from __future__ import annotations

import torch
from lerobot.policies.pretrained import PreTrainedPolicy

from cnep.runtime import STATE_KEY, STATE_NAMES, load_policy
from cnep.runtime.errors import PolicyError
from lerobot_policy_cnep.adapter import env_action, policy_observation
from lerobot_policy_cnep.configuration_cnep import NOT_TRAINED_HERE, TYPE, CNEPConfig


class CNEPPolicy(PreTrainedPolicy):
    """The policy folder `config.policy_dir` (CNEPConfig), one episode at a time."""

    config_class = CNEPConfig
    name = TYPE

    def __init__(self, config: CNEPConfig, **kwargs) -> None:
        super().__init__(config)
        if not config.policy_dir:
            raise PolicyError("--policy.policy_dir: give the folder `cnep export` wrote")
        self.policy = load_policy(config.policy_dir, threads=config.threads)
        self.columns = [STATE_NAMES.index(name) for name in self.policy.action_names]

    def reset(self) -> None:
        """A new episode: the policy's conditioning set emptied, the next observation its step 0."""
        self.policy.reset()

    @torch.no_grad()
    def select_action(self, batch: dict[str, torch.Tensor], **kwargs) -> torch.Tensor:
        """The action (1, 8) float32 for the batch of one episode's observation."""
        observation = policy_observation({k: v.cpu().numpy() for k, v in batch.items() if torch.is_tensor(v)})
        waypoint = self.policy.select_action(observation)  # (1, dy)
        return torch.from_numpy(env_action(observation[STATE_KEY], waypoint, self.columns))

    def predict_action_chunk(self, batch: dict[str, torch.Tensor], **kwargs) -> torch.Tensor:
        """The next action as a chunk of one, (1, 1, 8): the policy reconditions on every observation."""
        return self.select_action(batch).unsqueeze(1)

    def forward(self, batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, dict | None]:
        raise PolicyError(NOT_TRAINED_HERE)

    def get_optim_params(self) -> dict:
        raise PolicyError(NOT_TRAINED_HERE)
