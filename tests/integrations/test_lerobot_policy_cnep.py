"""The LeRobot plugin (integrations/lerobot_policy_cnep): what it changes between LeRobot's conventions and cnep's,
on numpy alone, and, where LeRobot is installed (its own environment, never the project's), its registration."""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from cnep.runtime import IMAGE_KEY_PREFIX, STATE_KEY, STATE_NAMES, PolicyError

PLUGIN = Path(__file__).resolve().parents[2] / "integrations" / "lerobot_policy_cnep"


def load_adapter():
    """The plugin's adapter module, loaded from its file: its package imports LeRobot, the adapter numpy alone."""
    spec = importlib.util.spec_from_file_location("cnep_lerobot_adapter", PLUGIN / "lerobot_policy_cnep" / "adapter.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


adapter = load_adapter()
CAMERA = IMAGE_KEY_PREFIX + "front"


def test_lerobot_imports_the_plugin_by_its_distribution_name():
    # register_third_party_plugins imports each distribution named lerobot_policy_* as a module of that very name.
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((PLUGIN / "pyproject.toml").read_text())["project"]
    assert project["name"].startswith("lerobot_policy_")
    assert (PLUGIN / project["name"] / "__init__.py").is_file()


def test_a_sim_observation_goes_under_lerobots_gym_keys():
    frame, state = np.zeros((120, 160, 3), np.uint8), np.arange(8, dtype=np.float32)
    mapped = adapter.gym_observation({CAMERA: frame, STATE_KEY: state})
    assert set(mapped) == {"pixels", "agent_pos"}
    assert mapped["pixels"]["front"] is frame and mapped["agent_pos"] is state
    assert set(adapter.gym_observation({STATE_KEY: state})) == {"agent_pos"}  # no camera: no pixels
    with pytest.raises(PolicyError, match="'depth'"):
        adapter.gym_observation({"depth": frame})


def test_each_gym_key_is_declared_with_the_policys_key_kind_and_shape():
    features = adapter.policy_features({CAMERA: (120, 160, 3), STATE_KEY: (8,)})
    assert features == {"pixels/front": (CAMERA, "VISUAL", (120, 160, 3)), "agent_pos": (STATE_KEY, "STATE", (8,))}


def test_the_batch_of_one_episode_is_the_runtimes_observation_without_the_task():
    batch = {CAMERA: np.zeros((1, 3, 120, 160), np.float32), STATE_KEY: np.ones((1, 8), np.float32), "task": [""]}
    observation = adapter.policy_observation(batch)
    assert set(observation) == {CAMERA, STATE_KEY}
    assert observation[STATE_KEY].shape == (1, 8)
    with pytest.raises(PolicyError, match="--eval.batch_size=1"):
        adapter.policy_observation({STATE_KEY: np.ones((2, 8), np.float32)})
    with pytest.raises(PolicyError, match="no 'observation.state'"):
        adapter.policy_observation({CAMERA: batch[CAMERA]})


def test_the_action_is_the_state_with_the_predicted_columns_replaced():
    state = np.arange(8, dtype=np.float32)[None]  # (1, 8)
    columns = [STATE_NAMES.index(name) for name in ("x", "y", "z", "gripper")]
    action = adapter.env_action(state, np.array([[10.0, 11.0, 12.0, 0.04]]), columns)
    assert action.shape == (1, 8) and action.dtype == np.float32
    np.testing.assert_allclose(action[0], [10, 11, 12, 3, 4, 5, 6, 0.04], rtol=1e-6)
    assert state[0, 0] == 0  # the observation is left as it was
    with pytest.raises(PolicyError, match=r"\(1, 4\)"):
        adapter.env_action(state, np.zeros((1, 3)), columns)


def test_lerobot_knows_the_policy_and_env_types_once_the_plugin_is_registered():
    pytest.importorskip("lerobot", reason="LeRobot lives in its own environment (docs/how-to/lerobot-dataset.md)")
    pytest.importorskip("lerobot_policy_cnep", reason="the plugin is installed in LeRobot's environment only")
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.configs import EnvConfig
    from lerobot.policies.factory import get_policy_class
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    assert "lerobot_policy_cnep" in sys.modules
    assert "cnep" in PreTrainedConfig.get_known_choices() and "cnep" in EnvConfig.get_known_choices()
    assert get_policy_class("cnep").__name__ == "CNEPPolicy"
