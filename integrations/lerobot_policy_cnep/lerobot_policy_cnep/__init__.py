"""cnep's exported policies and simulator tasks in LeRobot (0.4): the policy type `cnep` and the env type `cnep`.

    pip install -e integrations/lerobot_policy_cnep       # in LeRobot's environment, beside cnep-pipeline
    lerobot-eval --policy.type=cnep --policy.policy_dir=policy/ --env.type=cnep --env.task=Obstacle-v0 \
        --eval.batch_size=1 --eval.n_episodes=10

LeRobot imports this package by its distribution's name (lerobot.utils.import_utils.register_third_party_plugins);
importing it registers the policy's config (configuration_cnep), whose policy class and processors LeRobot then
finds by the type's name (modeling_cnep, processor_cnep), and the environments (env_cnep). adapter holds what
changes between LeRobot's conventions and cnep's, on numpy alone.
"""

import cnep.sim  # noqa: F401  (registers the cnep/<task> environments)
from lerobot_policy_cnep.configuration_cnep import CNEPConfig
from lerobot_policy_cnep.env_cnep import CnepEnv, register_envs

register_envs()

__all__ = ["CNEPConfig", "CnepEnv"]
