"""The baselines in the closed loop, behind the CNEP's interface: ProMP, GMM-GMR and nearest-demonstration retrieval
(cnep.models.baselines), each a `runtime.conditioning.Network` (models.baselines.network) inside a `runtime.Policy`
that reads the camera with the exported CNEP's feature graph and the state as the CNEP does, fitted here on the
training trajectories, and driven as the CNEP is.

What a baseline shares with the CNEP it is fitted beside: the conditioning set (the CNEP's `ConditioningPolicy`: its
anchors and window, the observations of the set handed to the method as they are), the waypoints, the time base and
the gripper command (runtime.gripper: the CNEP's threshold and hysteresis) of its `runtime.Policy`, and the
environment's observation noise, which ProMP and GMM-GMR condition with (`observation_noise`). It sees the features
reduced by PCA: `components` principal components fitted on the training frames' features (in the CNEP's normalised
units), beside the 8 state values. A demonstration is its rows resampled over its phase to the steps its method takes
(BASELINES: ProMP and the nearest demonstration at the motion's control steps, `motion_steps`; ProMP with a basis
function per step, `promp_basis`), and a method that draws (GMM-GMR's initialisation) draws with the training seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cnep.models.baselines import GMMGMR, NearestDemo, ProMP
from cnep.models.baselines.base import Method, resample
from cnep.models.baselines.network import BaselineNetwork, ReducedNetwork, Reduction
from cnep.models.baselines.promp import LEAST_SQUARES
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.run.config import CONFIG_FILE
from cnep.pipeline.workers import process_pool
from cnep.recordings import read_trajectory
from cnep.recordings.constants import BLOCK_FEATURES
from cnep.runtime import Policy
from cnep.runtime.exported import load_features
from cnep.runtime.jsonfile import read_json
from cnep.runtime.manifest import read_manifest
from cnep.runtime.spans import span_indices
from cnep.runtime.spec import PolicySpec
from cnep.runtime.timebase import TimeBase

if TYPE_CHECKING:  # the simulator loads MuJoCo
    from cnep.sim.task import Task

PROMP_STEPS_PER_BASIS = 1  # control steps of the motion per ProMP basis function: its fastest phases take 3-5 steps
GMM_STEPS = 16  # GMM-GMR's Gaussians span a whole demonstration (steps x columns): more and their densities underflow
GMM_COMPONENTS = 4
CHECKPOINTS = "checkpoints"  # `cnep sim`'s folder of checkpoints, beside its folder of exported policies


def motion_steps(time_base: TimeBase) -> int:
    """The control steps of the training demonstrations' motion (their median duration over their step period, the
    first step and the last)."""
    return round(time_base.duration_s / time_base.period_s) + 1


def promp_basis(steps: int) -> int:
    """ProMP's basis functions per dimension for a motion of `steps` control steps."""
    return math.ceil(steps / PROMP_STEPS_PER_BASIS)


# name -> (motion's control steps, training seed) -> a new method and the steps its demonstrations are resampled to.
BASELINES: dict[str, Callable[[int, int], tuple[Method, int]]] = {
    "ProMP": lambda steps, seed: (ProMP(n_weights=promp_basis(steps), estimator=LEAST_SQUARES), steps),
    "GMM-GMR": lambda steps, seed: (GMMGMR(n_components=GMM_COMPONENTS, seed=seed), GMM_STEPS),
    "Nearest": lambda steps, seed: (NearestDemo(), steps),
}


PCA_CNEP = "CNEP-PCA"  # the CNEP trained on the baselines' inputs: the features' principal components and the state
COMPARED = (*BASELINES, PCA_CNEP)  # the rows `baselines` adds to the table


def baseline_jobs(train_seeds: tuple[int, ...], policies: dict[str, Path]) -> dict[str, tuple[Path, tuple[str, int]]]:
    """Every baseline and the CNEP on their inputs, per training seed: label `NAME-seedN` -> (that seed's exported
    CNEP in `policies`, whose normaliser, feature graph and conditioning they take, (NAME, N))."""
    return {
        f"{name}-seed{seed}": (policies[f"CNEP-seed{seed}"], (name, seed)) for seed in train_seeds for name in COMPARED
    }


def baseline_policy(
    name: str,
    cnep: Path,
    trajectories: list[Path],
    components: int,
    waypoints: int,
    seed: int,
    pose_noise: tuple[float, float] = (0.0, 0.0),
) -> Policy:
    """The baseline `name` (a COMPARED entry) as a policy, fitted on the `trajectories` (MCAP) with the exported CNEP
    `cnep`'s normaliser, spec, conditioning and feature graph, the features reduced to `components`; seed: the
    training seed; pose_noise: the environment's observation noise (m per axis, degrees per axis of the orientation's
    error: sim.robot.RobotSettings.pose_noise_m, pose_noise_deg). PCA_CNEP is a CNEP trained as the one in `cnep`
    was (its checkpoint: the folder of `cnep`'s name in CHECKPOINTS beside `cnep`'s folder), on the reduced rows."""
    spec = read_manifest(cnep).spec
    cols = span_indices(spec.columns.observed)
    demos = [_normalised_rows(spec, read_trajectory(path))[:, cols] for path in trajectories]
    check_components(components, len(np.concatenate(demos)), spec.features[1] - spec.features[0])
    reduction = Reduction.fit(spec, np.concatenate(demos), components)
    rest = [c for c in cols if c not in set(range(*spec.features))]
    predicted = np.array([components + rest.index(c) for c in span_indices(spec.columns.predicted)])
    if name == PCA_CNEP:
        checkpoint = cnep.parent.parent / CHECKPOINTS / cnep.name
        network = pca_cnep(checkpoint, [reduction(d) for d in demos], predicted, reduction, seed)
        return Policy(network, spec, load_features(cnep, threads=1), waypoints=waypoints)
    steps = motion_steps(spec.time_base)
    method, resampled = BASELINES[name](steps, seed)
    grid = np.linspace(0.0, 1.0, resampled)
    reduced = np.stack([resample(reduction(d), grid) for d in demos])  # (N, resampled, k + rest)
    noise = observation_noise(spec, rest, components, pose_noise)
    network = BaselineNetwork(method.fit(reduced), reduction, predicted, slots=steps, noise=noise)
    one = replace(spec, n_experts=1)  # the gate of one expert; the conditioning, time base and gripper the CNEP's
    return Policy(network, one, load_features(cnep, threads=1), waypoints=waypoints)


def pca_cnep(
    checkpoint: Path, reduced: list[np.ndarray], predicted: np.ndarray, reduction: Reduction, seed: int
) -> ReducedNetwork:
    """A CNEP of the checkpoint's settings (its model's but the columns, its training's with `seed`) trained on the
    `reduced` rows (T_i, k + rest) of the training demonstrations, observing them whole and predicting their
    `predicted` columns, as a Network of the full rows. It trains in a process of its own: torch's optimiser loads a
    library that crashes a process holding a MuJoCo renderer's context, as a closed-loop worker may."""
    from cnep.models import CNEP, CNEPConfig  # torch: imported where a CNEP runs
    from cnep.models.online import TorchNetwork, model_columns

    saved = read_json(checkpoint / CONFIG_FILE)
    with process_pool(1) as pool:
        config, state = pool.submit(_fit_reduced, saved["model"], saved["training"], reduced, predicted, seed).result()
    model = CNEP(CNEPConfig.from_dict(config))
    model.load_state_dict({name: torch_tensor(value) for name, value in state.items()})
    return ReducedNetwork(TorchNetwork(model.eval()), reduction, model_columns(model), predicted)


def torch_tensor(value: np.ndarray):
    """`value` as a torch tensor (torch imported on first use)."""
    import torch

    return torch.from_numpy(value)


def _fit_reduced(
    model: dict, training: dict, reduced: list[np.ndarray], predicted: np.ndarray, seed: int
) -> tuple[dict, dict[str, np.ndarray]]:
    """pca_cnep's training, in its process: the trained model's config (CNEPConfig.to_dict) and its state (numpy)."""
    from cnep.models import CNEPConfig, TrainConfig
    from cnep.models.config import ColumnRoles
    from cnep.models.train import fit

    width = reduced[0].shape[1]
    spans = tuple((int(c), int(c) + 1) for c in predicted)
    roles = ColumnRoles(width=width, observed=((0, width),), query=(), predicted=spans)
    config = replace(CNEPConfig.from_dict(model), columns=roles)
    known = {f.name for f in fields(TrainConfig)}
    train = replace(TrainConfig.from_dict({k: v for k, v in training.items() if k in known}), seed=seed)
    fitted, _ = fit([r.astype(np.float32) for r in reduced], config, train, progress=False)
    return fitted.config.to_dict(), {name: value.numpy() for name, value in fitted.state_dict().items()}


def observation_noise(
    spec: PolicySpec, rest: list[int], components: int, pose_noise: tuple[float, float]
) -> np.ndarray:
    """The variance (k + rest,) of a reduced row's observation, in the CNEP's normalised units, that the environment's
    pose noise (m per axis, degrees per axis of rotation) gives: a position's its square, a quaternion entry's that of
    half the angle (a small turn by a moves an entry by at most a / 2); 0 for the components and the gripper (the
    frames' noise reaches the features through the camera, as it does the CNEP's)."""
    position_m, turn_deg = pose_noise
    per_entry = np.array([position_m] * 3 + [math.radians(turn_deg) / 2] * 4 + [0.0])  # (8,) std: STATE_NAMES' order
    noise = np.zeros(components + len(rest))
    for (s0, s1), (r0, r1) in spec.state:
        for s, r in zip(range(s0, s1), range(r0, r1)):
            if r in rest:
                noise[components + rest.index(r)] = (per_entry[s] / float(spec.columns.scale[r])) ** 2
    return noise


def environment_pose_noise(task: Task, settings) -> tuple[float, float]:
    """The pose noise (m per axis, degrees per axis of rotation) of the environment the loop runs `task` in with
    `settings` (pipeline.sim.config: the task's variants): its robot's (sim.robot.RobotSettings)."""
    env = task.make_env(
        task.conditions[0] if task.conditions else None, 1, **{v: getattr(settings, v) for v in task.variants}
    )
    try:
        return env.robot.pose_noise_m, env.robot.pose_noise_deg
    finally:
        env.close()


def check_components(components: int, frames: int, features: int) -> None:
    """PipelineError naming --pca unless `frames` training frames of `features` features have `components` principal
    components (at most one per feature and one per frame)."""
    most = min(frames, features)
    if components > most:
        raise PipelineError(
            f"--pca {components}: the training frames' features have {most} principal components ({frames} frames "
            f"of {features} features); choose --pca {most} or fewer"
        )


def _normalised_rows(spec: PolicySpec, trajectory) -> np.ndarray:
    """A trajectory's model rows (T, width) as the policy builds them (features, then the state by `spec.state`),
    normalised with the CNEP's loc and scale."""
    data = trajectory.data
    rows = np.zeros((len(data), spec.columns.width), np.float64)
    a, b = spec.features
    f0, f1 = trajectory.blocks[BLOCK_FEATURES]
    rows[:, a:b] = data[:, f0:f1]
    state = data[:, f1:]  # the pose and the gripper after the features: runtime.spec.STATE_NAMES' order
    for (s0, s1), (r0, r1) in spec.state:
        rows[:, r0:r1] = state[:, s0:s1]
    return (rows - spec.columns.loc) / spec.columns.scale
