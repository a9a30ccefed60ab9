import numpy as np
import pytest
import torch

from cnep.models.errors import ConfigError
from cnep.models.normaliser import Moments, Normaliser


def _trajectories(seed=0):
    """Trajectories of different lengths whose columns have very different means and spreads, and one constant."""
    rng = np.random.default_rng(seed)
    centres, spreads = np.array([0.0, 0.5, 300.0, 7.0]), np.array([1.0, 0.01, 2.0, 0.0])
    return [(centres + spreads * rng.standard_normal((T, 4))).astype(np.float32) for T in (3, 40, 17, 100, 1)]


def _fit_on_every_row(trajectories) -> tuple[torch.Tensor, torch.Tensor]:
    """The fit on all rows held together (float64 concatenation, numpy's two-pass std): the reference."""
    rows = np.concatenate([np.asarray(t, dtype=np.float64) for t in trajectories])
    std = rows.std(axis=0)
    scale = np.where(std > 1e-8 * (1 + np.abs(rows).max(axis=0)), std, 1.0)
    return torch.from_numpy(rows.mean(axis=0)).float(), torch.from_numpy(scale).float()


@pytest.mark.parametrize("seed", range(5))
def test_the_fit_from_running_moments_equals_the_fit_on_every_row_together(seed):
    trajectories = _trajectories(seed)
    fitted = Normaliser(4).fit(trajectories)
    loc, scale = _fit_on_every_row(trajectories)
    assert torch.equal(fitted.loc, loc) and torch.equal(fitted.scale, scale)
    assert fitted.scale[3] == 1.0  # the constant column maps to 0, not to inf


def test_moments_combine_alike_in_any_grouping():
    trajectories = _trajectories()
    whole = Moments.of(np.concatenate(trajectories))
    per_file = Moments.total(Moments.of(t) for t in trajectories)
    two_ranks = Moments.total(Moments.of(t) for t in trajectories[::2]) + Moments.total(
        Moments.of(t) for t in trajectories[1::2]
    )
    for combined in (per_file, two_ranks):
        assert combined.count == whole.count
        np.testing.assert_allclose(combined.mean, whole.mean, rtol=1e-13)
        np.testing.assert_allclose(combined.m2, whole.m2, rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(combined.largest, whole.largest)


def test_a_column_too_large_to_normalise_is_named():
    trajectories = [t.astype(np.float64) for t in _trajectories()]
    trajectories[1][5, 2] = 1e300  # finite, but its square is not
    with pytest.raises(
        ConfigError, match=r"Column 2 holds values too large to normalise \(largest magnitude 1e\+300\)"
    ):
        Normaliser(4).fit(trajectories)


def test_no_trajectories_is_an_error():
    with pytest.raises(ConfigError, match="at least one trajectory"):
        Normaliser(4).fit([])
