"""The baselines in the closed loop as `cnep sim` fits them: ProMP's basis functions follow the motion's length, every
baseline (and the CNEP on their inputs) runs beside every training seed's CNEP, and the environment's pose noise
reaches their conditioning in the CNEP's normalised units (tests/models/test_baselines.py: the conditioning set and
the gripper command)."""

import math

import numpy as np

from cnep.pipeline.sim.baselines import (
    BASELINES,
    COMPARED,
    PCA_CNEP,
    PROMP_STEPS_PER_BASIS,
    baseline_jobs,
    motion_steps,
    observation_noise,
    promp_basis,
)
from cnep.runtime import TimeBase
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.pick_place import scene as P
from tests.runtime.fakes import FEATURES, WIDTH, camera_spec


def test_promp_has_a_basis_function_per_step_of_the_motion_and_at_least_30_in_every_task():
    shortest = {"obstacle": O.DEMO_STEPS[0], "pick-place": sum(low for low, _ in P.PHASE_STEPS.values())}
    for steps in shortest.values():
        assert promp_basis(steps) >= 30
    for steps in (shortest["obstacle"], 65, 120):
        method, resampled = BASELINES["ProMP"](steps, 0)
        assert method.n_weights == promp_basis(steps) == math.ceil(steps / PROMP_STEPS_PER_BASIS)
        assert resampled == steps
    assert motion_steps(TimeBase(6.4, 0.1)) == 65  # a median demonstration of 6.4 s at 10 Hz: 65 steps


def test_every_baseline_and_the_cnep_on_their_inputs_run_beside_every_training_seeds_cnep():
    policies = {f"{model}-seed{seed}": f"{model.lower()}-{seed}" for model in ("CNEP", "CNMP") for seed in (0, 3)}
    jobs = baseline_jobs((0, 3), policies)
    assert set(COMPARED) == {*BASELINES, PCA_CNEP}
    assert set(jobs) == {f"{name}-seed{seed}" for name in COMPARED for seed in (0, 3)}
    for name in COMPARED:
        assert jobs[f"{name}-seed3"] == ("cnep-3", (name, 3))
    assert BASELINES["GMM-GMR"](40, 3)[0].seed == 3  # a method that draws, draws with the training seed


def test_the_environments_pose_noise_is_the_baselines_observation_noise_in_normalised_units():
    spec = camera_spec()  # observes the whole row: 6 features, then x y z qx qy qz qw gripper
    rest = list(range(FEATURES, WIDTH))
    noise = observation_noise(spec, rest, components=2, pose_noise=(0.002, 1.0))
    scale = spec.columns.scale[FEATURES:].astype(np.float64)
    expected = np.r_[0.0, 0.0, (0.002 / scale[:3]) ** 2, (math.radians(1.0) / 2 / scale[3:7]) ** 2, 0.0]
    np.testing.assert_allclose(noise, expected, rtol=1e-6)
    assert not observation_noise(spec, rest, components=2, pose_noise=(0.0, 0.0)).any()
