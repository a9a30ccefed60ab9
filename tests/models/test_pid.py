"""The PID controller: the executed trajectory passes through the conditioning points and converges
back to the generated trajectory as the correction decays."""

import numpy as np
import pytest

from cnep.models.errors import ConfigError
from cnep.models.pid import PIDGains, correction_weights, pid_track, reference


def generated(T: int = 120) -> np.ndarray:
    t = np.linspace(0, 1, T)
    return np.stack([np.sin(np.pi * t), 0.5 * t**2], axis=1)  # (T, 2)


def test_started_on_the_reference_the_trajectory_passes_through_every_point():
    y = generated()
    k = np.array([0, 50, 119])
    c = y[k] + np.array([[0.3, -0.2], [-0.4, 0.1], [0.25, 0.3]])
    x = pid_track(y, k, c, PIDGains(decay_steps=15))
    np.testing.assert_allclose(x[k], c, atol=1e-9)
    far = np.all(np.abs(np.arange(len(y))[:, None] - k[None]) >= 15, axis=1)  # beyond every decay window
    assert far.sum() > 50
    np.testing.assert_allclose(x[far], y[far], atol=1e-9)


def test_overlapping_corrections_still_pass_exactly_through_the_points():
    y = generated()
    k = np.array([40, 45, 52])
    c = y[k] + np.array([[0.5, 0.0], [-0.5, 0.2], [0.3, -0.3]])
    np.testing.assert_allclose(reference(y, k, c, decay_steps=20)[k], c, atol=1e-9)


def test_started_off_the_path_the_error_decays_and_the_trajectory_converges_back():
    y = generated(200)
    k = np.array([0, 100])
    c = y[k] + np.array([[0.2, 0.2], [-0.3, 0.1]])
    x = pid_track(y, k, c, PIDGains(decay_steps=20), start=y[0] + np.array([1.0, -1.0]))
    ref = reference(y, k, c, decay_steps=20)
    err = np.abs(x - ref).max(axis=1)  # (T,)
    assert err[0] == pytest.approx(1.2)  # |(y0 - 1) - (y0 + 0.2)|: starts far from the reference
    assert err[60:].max() < 1e-3  # settled well before the second point
    np.testing.assert_allclose(x[100], c[1], atol=1e-3)  # passes through the later point
    np.testing.assert_allclose(x[-40:], y[-40:], atol=1e-3)  # back on the generated trajectory


def test_one_dimensional_input_keeps_its_shape():
    y = generated()[:, 0]
    x = pid_track(y, [10], [2.0])
    assert x.shape == y.shape and x[10] == pytest.approx(2.0)


def test_correction_weight_is_one_at_the_point_and_zero_after_decay_steps():
    w = correction_weights(30, np.array([10]), decay_steps=5)[:, 0]
    assert w[10] == 1.0 and w[15] == 0.0 and w[5] == 0.0 and 0 < w[12] < 1


@pytest.mark.parametrize("indices", [[-1], [120], [3, 3]])
def test_bad_conditioning_indices_are_refused(indices):
    with pytest.raises(ConfigError, match="distinct steps"):
        pid_track(generated(), indices, np.zeros((len(indices), 2)))


def test_negative_gains_are_refused():
    with pytest.raises(ConfigError, match="gains"):
        PIDGains(kp=-0.5)
