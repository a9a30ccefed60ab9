"""Baselines: each fits, conditions (passes through or near the conditioning points; with observation noise, less
closely), the lookup is exact, and as a runtime network one sees the conditioning set a CNEP sees and drives the
gripper as a CNEP does."""

from dataclasses import replace

import numpy as np
import pytest

from cnep.models.baselines import GMMGMR, BaselineNetwork, NearestDemo, ProMP, ReducedNetwork, Reduction, base
from cnep.models.baselines.promp import CONDITION_FLOOR, LEAST_SQUARES
from cnep.models.errors import ConfigError
from cnep.models.evaluation import paper_queries
from cnep.models.synthetic import make_set
from cnep.runtime import STATE_KEY, Columns, ConditioningPolicy, GripperCommand, Policy
from cnep.runtime.conditioning import Conditioner
from tests.runtime.fakes import FEATURES, WIDTH, camera_spec, mean_colour_features
from tests.runtime.test_policy import observation


def two_modes(n: int = 12, T: int = 40, seed: int = 0):
    """Rises and falls from 0 to +-1 with a small offset each: (n, T, 1) and modes (n,)."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)
    modes = np.arange(n) % 2
    demos = np.stack([(1 if k else -1) * np.sin(np.pi * t / 2) + 0.02 * rng.standard_normal() for k in modes])
    return demos[..., None], modes


def conditioned_error(method, demos, obs_steps) -> tuple[float, float]:
    """Generate from the demo-0 points at obs_steps: (max error at those points, MSE to demo 0)."""
    T = demos.shape[1]
    t = np.arange(T) / (T - 1)
    obs_t, obs_y = t[obs_steps], demos[0, obs_steps]
    out = method.generate(obs_t, obs_y, t)
    assert out.shape == (T, 1)
    return float(np.abs(out[obs_steps] - obs_y).max()), float(np.mean((out - demos[0]) ** 2))


@pytest.mark.parametrize("estimator", ["em", LEAST_SQUARES])
def test_promp_passes_through_the_conditioning_points(estimator):
    demos, _ = two_modes()
    at_points, mse = conditioned_error(ProMP(n_weights=8, estimator=estimator).fit(demos), demos, [10, 39])
    assert at_points < 0.05 and mse < 0.01  # the end point tells the modes apart: the other mode is ~1 away


def test_promp_by_least_squares_learns_the_weights_gaussian_the_em_learns():
    demos, _ = two_modes()
    em, least = ProMP(n_weights=8).fit(demos).promp, ProMP(n_weights=8, estimator=LEAST_SQUARES).fit(demos).promp
    t = np.linspace(0, 1, demos.shape[1])
    mean_em, mean_least = (p.trajectory_from_weights(t, p.weight_mean) for p in (em, least))
    assert np.abs(mean_least - demos.mean(axis=0)).max() < 0.02  # the demonstrations' mean, through the basis
    assert np.abs(mean_least - mean_em).max() < 0.02
    basis = least._rbfs_nd_sequence(t)  # (W, T)
    spread = np.sqrt(np.diag(basis.T @ least.weight_cov @ basis))  # (T,)
    assert abs(spread[-1] - demos[:, -1, 0].std(ddof=1)) < 0.05  # the two modes' spread at the end: about 1
    with pytest.raises(ValueError, match="estimator must be"):
        ProMP(estimator="gradient")


@pytest.mark.parametrize("ridge", [1e-3, 0.0])
def test_gmm_gmr_keeps_the_conditioning_points_and_picks_the_mode(ridge):
    demos, _ = two_modes()
    at_points, mse = conditioned_error(GMMGMR(n_components=2, ridge=ridge, seed=0).fit(demos), demos, [10, 39])
    assert at_points < 1e-9  # GMR fills in the unobserved steps; the observed ones are the conditioning values
    assert mse < 0.01  # the end point tells the modes apart: the other mode is ~1 away


def test_gmm_ridge_floors_the_covariances():
    demos, _ = two_modes()
    gmm = GMMGMR(n_components=2, ridge=1e-2, seed=0).fit(demos)
    floor = 1e-2 * np.ptp(demos) ** 2
    assert min(np.linalg.eigvalsh(c).min() for c in gmm.gmm.covariances) >= floor * (1 - 1e-6)


def test_nearest_demo_returns_the_closest_demonstration():
    demos, _ = two_modes(n=6)
    T = demos.shape[1]
    t = np.arange(T) / (T - 1)
    method = NearestDemo().fit(demos)
    for i in range(len(demos)):
        obs_y = demos[i, [5, 30]] + 1e-4
        assert method.nearest(t[[5, 30]], obs_y) == i
        np.testing.assert_allclose(method.generate(t[[5, 30]], obs_y, t), demos[i])


def test_generate_resamples_at_arbitrary_query_times():
    demos, _ = two_modes(n=4)
    out = NearestDemo().fit(demos).generate(np.array([1.0]), demos[2, -1:], np.array([0.0, 0.5 / 39, 1.0]))
    np.testing.assert_allclose(out[:, 0], [demos[2, 0, 0], 0.5 * (demos[2, 0, 0] + demos[2, 1, 0]), demos[2, -1, 0]])


def test_missing_library_names_the_extra(monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "gmr", None)  # import gmr -> ImportError
    with pytest.raises(ConfigError, match=r"pip install \.\[baselines\]"):
        base.require("gmr", "gmr")


def test_bad_demonstrations_are_refused():
    with pytest.raises(ConfigError, match=r"\(N, T, dy\)"):
        NearestDemo().fit(np.zeros((4, 10)))


@pytest.mark.slow
def test_gmm_without_ridge_flags_conditionals_on_empty_components():
    """Plain EM on 32 bimodal demonstrations with the authors' 20 components leaves empty components
    (prior ~1e-17, mean 0, covariance 0); the library's conditional puts its weight on them for most
    paper-protocol queries and would predict 0 at every unobserved step: those outputs must be NaN."""
    data = make_set("bimodal", seed=0)
    demos, modes = data.train[:32], data.train_modes[:32]
    queries = paper_queries(demos, modes, n=4, seed=0)
    t = np.arange(demos.shape[1]) / (demos.shape[1] - 1)
    plain = GMMGMR(n_components=20, ridge=0.0, seed=0).fit(demos)
    assert (plain.gmm.priors < 1e-12).any()
    flagged = [np.isnan(plain.generate(q.obs_t, q.obs_y, t)).all() for q in queries]
    assert sum(flagged) >= 3
    for q, bad in zip(queries, flagged):
        if not bad:
            assert np.isfinite(plain.generate(q.obs_t, q.obs_y, t)).all()
    ridge = GMMGMR(n_components=20, seed=0).fit(demos)  # the same data with the default ridge: all finite
    assert all(np.isfinite(ridge.generate(q.obs_t, q.obs_y, t)).all() for q in queries)


class Recording:
    """A method that records the observations it is conditioned on and predicts the `path` (T, dy) it is given."""

    def __init__(self, path: np.ndarray) -> None:
        self.path, self.seen = path, []

    def generate(self, obs_t, obs_y, query_t, noise=None):
        self.seen.append((np.array(obs_t), np.array(obs_y)))
        return base.resample(self.path, np.asarray(query_t))


def reduction(rng: np.random.Generator) -> Reduction:
    """3 features reduced to 2 components, then 2 other observed columns (an observed row of 5)."""
    return Reduction(np.arange(3), np.arange(3, 5), rng.normal(size=3), rng.normal(size=(3, 2)))


def test_a_baseline_sees_the_observations_of_the_cnep_conditioning_set():
    rng = np.random.default_rng(0)
    reduce = reduction(rng)
    columns = Columns(((0, 5),), (), ((3, 5),), rng.normal(size=5), rng.uniform(0.5, 2, 5))
    method = Recording(np.zeros((10, 4)))
    slots = 12  # the motion's control steps: step k at phase k / 11
    set_policy = ConditioningPolicy(window=3, anchors=1)
    conditioner = Conditioner(BaselineNetwork(method, reduce, np.array([2, 3]), slots), columns, set_policy)
    rows = rng.normal(size=(8, 5))
    t = np.arange(8) / (slots - 1)
    for k in range(8):
        conditioner.step(rows[k].astype(np.float32), t[k], np.array([t[k] + 0.1]))
        held = [0, *range(max(1, k - 2), k + 1)]  # the anchor and the latest 3: the CNEP's set at step k
        assert conditioner.n_conditioning == len(held)
        seen_t, seen_y = method.seen[-1]
        normalised = (rows[held].astype(np.float32) - columns.loc) / columns.scale
        np.testing.assert_allclose(seen_t, t[held], atol=1e-6)
        np.testing.assert_allclose(seen_y, reduce(normalised), atol=1e-5)
    for _ in range(2):  # after the motion's end the phase stays at 1: those steps are one observation, their mean
        conditioner.step(rows[0].astype(np.float32), 1.0, np.array([1.0]))
    seen_t, seen_y = method.seen[-1]
    np.testing.assert_allclose(seen_t, [0.0, t[7], 1.0], atol=1e-6)
    assert conditioner.n_conditioning == 4  # the anchor, step 7, and the two at phase 1


def test_a_baseline_gripper_command_crosses_where_its_prediction_does():
    """The measured gripper stays open; the nearest demonstration, conditioned on it, predicts the closing, and the
    policy's command (the CNEP's threshold and hysteresis) closes."""
    spec = camera_spec()
    gripper_col = WIDTH - 1
    open_, closed = 0.04, 0.012
    command = GripperCommand.from_levels(closed, open_)
    reduce = Reduction(np.arange(FEATURES), np.arange(FEATURES, WIDTH), np.zeros(FEATURES), np.eye(FEATURES)[:, :2])
    gripper = np.r_[np.full(10, open_), np.full(11, closed)]  # (21,) data units: closes at step 10 (phase 0.5)
    demo = np.zeros((21, reduce.width))
    demo[:, -1] = (gripper - spec.columns.loc[gripper_col]) / spec.columns.scale[gripper_col]
    predicted = np.array([2, 3, 4, reduce.width - 1])  # x y z gripper in a reduced row
    network = BaselineNetwork(NearestDemo().fit(demo[None]), reduce, predicted, slots=21)  # the time base's steps
    policy = Policy(network, replace(spec, n_experts=1, gripper=command), mean_colour_features, waypoints=1)
    policy.reset()
    closes = []
    for k in range(20):
        obs = observation(k)
        obs[STATE_KEY][7] = open_
        closes.append(policy.step(obs).gripper_closed)
    assert closes == [False] * 9 + [True] * 11  # step 9's waypoint is step 10's: the demonstration's closing


def test_promp_and_gmm_condition_with_the_observation_noise():
    """An exact observation decides the mode; one whose noise dwarfs the demonstrations' spread tells nothing, and the
    prediction is the demonstrations' mean."""
    demos, _ = two_modes()
    T = demos.shape[1]
    t = np.arange(T) / (T - 1)
    for method in (ProMP(n_weights=8).fit(demos), GMMGMR(n_components=2, seed=0).fit(demos)):
        exact = method.generate(t[[20]], demos[0, [20]], t[[30]])[0, 0]
        noisy = method.generate(t[[20]], demos[0, [20]], t[[30]], noise=np.array([1e6]))[0, 0]
        assert abs(exact - demos[0, 30, 0]) < 0.05
        assert abs(noisy - demos[:, 30, 0].mean()) < 0.05


class Echo:
    """A network whose encoding is its input and whose every expert predicts `mean` (normalised)."""

    def __init__(self, mean: np.ndarray) -> None:
        self.mean = mean

    def encode(self, obs):
        return obs

    def decode(self, r, query):
        mean = np.broadcast_to(self.mean, (2, len(query), len(self.mean))).astype(np.float32)
        return np.array([0.5, 0.5], np.float32), mean, np.ones_like(mean)


def test_the_cnep_on_the_principal_components_reads_reduced_rows_and_predicts_in_the_full_rows_units():
    rng = np.random.default_rng(0)
    reduce = reduction(rng)  # an observed row of 5 -> 2 components + 2 other columns
    inner = Columns(((0, 4),), (), ((2, 4),), rng.normal(size=4), rng.uniform(0.5, 2, 4))  # the reduced rows' stats
    predicted = np.array([2, 3])
    network = ReducedNetwork(Echo(np.array([0.5, -1.0])), reduce, inner, predicted)
    obs = np.concatenate([[[0.3]], rng.normal(size=(1, 5))], axis=1).astype(np.float32)  # [t, observed row]
    expected = (reduce(obs[:, 1:].astype(np.float64)) - inner.loc) / inner.scale
    np.testing.assert_allclose(network.encode(obs), np.concatenate([obs[:, :1], expected], axis=1), rtol=1e-5)
    _, mean, std = network.decode(network.encode(obs), np.zeros((3, 1), np.float32))
    np.testing.assert_allclose(mean[0, 0], np.array([0.5, -1.0]) * inner.scale[2:] + inner.loc[2:], rtol=1e-6)
    np.testing.assert_allclose(std[1, 2], inner.scale[2:], rtol=1e-6)


def test_promp_conditions_on_all_observations_at_once_as_the_library_does_one_by_one():
    demos, _ = two_modes()
    method = ProMP(n_weights=8).fit(demos)
    obs_t, obs_y, noise = np.array([0.2, 0.25, 0.3]), demos[3, [8, 10, 12]], np.array([0.01])
    step_by_step = method.promp
    for t, y in zip(obs_t, obs_y):
        step_by_step = step_by_step.condition_position(y, y_cov=np.diag(noise + CONDITION_FLOOR), t=t, t_max=1.0)
    t = np.linspace(0, 1, 40)
    expected = base.resample(step_by_step.mean_trajectory(base.grid(40)), t)
    np.testing.assert_allclose(method.generate(obs_t, obs_y, t, noise=noise), expected, atol=1e-8)
