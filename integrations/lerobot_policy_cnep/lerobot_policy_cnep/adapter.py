"""Between LeRobot's conventions and cnep's, on plain dicts and numpy arrays (no lerobot, torch or Gymnasium).

A cnep.sim environment observes with the keys a policy reads: `observation.images.<camera>` (H, W, 3) uint8 and
`observation.state` (8,) float32. LeRobot's `lerobot-eval` reads a Gymnasium environment's observation by the keys
of its gym packages instead, `pixels` (a dict camera -> frame) and `agent_pos`, and renames them to the policy's
(lerobot.envs.utils.preprocess_observation): `gym_observation` maps one to the other and `policy_features` names
each entry's policy key, kind and shape, as LeRobot's EnvConfig declares them.

The runtime's policy predicts a waypoint of its own columns (`Policy.action_names`, dy of them); the environment's
action is a whole (8,) state. `env_action` fills the columns the policy does not predict with the observed state,
as the project's episode driver acts (cnep.sim.episode.Driver).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from cnep.runtime.constants import IMAGE_KEY_PREFIX, STATE_KEY
from cnep.runtime.errors import PolicyError

PIXELS, AGENT_POS = "pixels", "agent_pos"  # LeRobot's gym keys (lerobot.envs.utils.preprocess_observation)
VISUAL, STATE = "VISUAL", "STATE"  # lerobot.configs.types.FeatureType's names


def gym_observation(observation: Mapping) -> dict:
    """A cnep.sim observation (or observation space: the values pass through) under LeRobot's gym keys:
    {"pixels": {camera: frame}, "agent_pos": state}; PolicyError for a key that is neither a camera nor the state."""
    pixels, other = {}, {}
    for key, value in observation.items():
        if key.startswith(IMAGE_KEY_PREFIX):
            pixels[key.removeprefix(IMAGE_KEY_PREFIX)] = value
        elif key == STATE_KEY:
            other[AGENT_POS] = value
        else:
            raise PolicyError(f"the observation's {key!r} has no LeRobot gym key (cameras and {STATE_KEY!r} do)")
    return {PIXELS: pixels, **other} if pixels else other


def policy_features(shapes: Mapping[str, tuple[int, ...]]) -> dict[str, tuple[str, str, tuple[int, ...]]]:
    """LeRobot gym key ("pixels/<camera>", "agent_pos") -> (the policy's key, VISUAL or STATE, shape) for a cnep.sim
    observation's `shapes` (key -> shape), as an EnvConfig's `features` and `features_map` declare them."""
    features = {}
    for key, shape in shapes.items():
        if key.startswith(IMAGE_KEY_PREFIX):
            features[f"{PIXELS}/{key.removeprefix(IMAGE_KEY_PREFIX)}"] = (key, VISUAL, tuple(shape))
        elif key == STATE_KEY:
            features[AGENT_POS] = (key, STATE, tuple(shape))
        else:
            raise PolicyError(f"the observation's {key!r} has no LeRobot gym key (cameras and {STATE_KEY!r} do)")
    return features


def policy_observation(batch: Mapping[str, object]) -> dict[str, np.ndarray]:
    """The runtime's observation from LeRobot's batch (key -> array, each with a batch dimension): the cameras (1, 3,
    H, W) float in [0, 1] and the state (1, 8), as they come; the rest (`task`, a language instruction) left out.
    PolicyError without a state, or for a batch of more than one episode: the policy runs one episode at a time
    (lerobot-eval's --eval.batch_size=1)."""
    if STATE_KEY not in batch:
        raise PolicyError(f"LeRobot's batch has no {STATE_KEY!r} (keys: {sorted(batch)})")
    observation = {
        key: np.asarray(value) for key, value in batch.items() if key == STATE_KEY or key.startswith(IMAGE_KEY_PREFIX)
    }
    for key, value in observation.items():
        if value.ndim < 2 or value.shape[0] != 1:
            raise PolicyError(
                f"{key}: a batch of one episode (1, ...) is what a cnep policy steps, got shape {value.shape}; "
                "run lerobot-eval with --eval.batch_size=1"
            )
    return observation


def env_action(state: np.ndarray, waypoint: np.ndarray, columns: Sequence[int]) -> np.ndarray:
    """The environment's action (1, 8) float32: the observed `state` (1, 8) with its entries `columns` (dy of them,
    the state's index of each of the policy's action names) replaced by the policy's `waypoint` (1, dy)."""
    if waypoint.shape != (1, len(columns)):
        raise PolicyError(f"a waypoint of shape (1, {len(columns)}) was expected, got {waypoint.shape}")
    action = np.array(state, dtype=np.float32, copy=True)
    action[:, list(columns)] = waypoint
    return action
