"""Baselines: each fits, conditions (passes through or near the conditioning points), and the lookup is exact."""

import numpy as np
import pytest

from cnep.models.baselines import GMMGMR, NearestDemo, ProMP, base
from cnep.models.errors import ConfigError
from cnep.models.evaluation import paper_queries
from cnep.models.synthetic import make_set


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


def test_promp_passes_through_the_conditioning_points():
    demos, _ = two_modes()
    at_points, _ = conditioned_error(ProMP(n_weights=8).fit(demos), demos, [10, 39])
    assert at_points < 0.05


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
