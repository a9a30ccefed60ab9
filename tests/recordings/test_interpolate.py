import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cnep.recordings import RecordingError
from cnep.recordings.interpolate import interpolate_linear, slerp


def z_rotation(angle):
    """Quaternions xyzw (N, 4) of rotations by `angle` (N,) rad about z."""
    return np.stack([np.zeros_like(angle), np.zeros_like(angle), np.sin(angle / 2), np.cos(angle / 2)], axis=1)


def test_linear_hits_samples_and_midpoints():
    t = np.array([0, 10, 30], dtype=np.int64)
    v = np.array([[0.0, 1.0], [10.0, 3.0], [30.0, -1.0]])
    np.testing.assert_allclose(interpolate_linear(t, v, t), v)
    np.testing.assert_allclose(interpolate_linear(t, v, np.array([5, 20])), [[5.0, 2.0], [20.0, 1.0]])


def test_slerp_follows_a_constant_rate_rotation_exactly():
    t = np.arange(0, 1_000_000_001, 100_000_000, dtype=np.int64)  # 10 Hz over 1 s
    omega = 2.5  # rad/s, so neighbours are 0.25 rad apart
    q = slerp(t, z_rotation(omega * t / 1e9), np.array([25_000_000, 555_000_000, 1_000_000_000]))
    expected = z_rotation(omega * np.array([0.025, 0.555, 1.0]))
    np.testing.assert_allclose(q, expected, atol=1e-12)
    # linear interpolation of the components would be off the unit sphere and lag the angle
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)


def test_slerp_takes_the_shorter_arc_across_a_sign_flip():
    t = np.array([0, 10], dtype=np.int64)
    q = np.concatenate([z_rotation(np.array([0.2])), -z_rotation(np.array([0.4]))])  # same as +0.4 rad
    mid = slerp(t, q, np.array([5]))
    np.testing.assert_allclose(np.abs(mid), np.abs(z_rotation(np.array([0.3]))), atol=1e-12)


def test_no_extrapolation():
    t = np.array([10, 20], dtype=np.int64)
    with pytest.raises(RecordingError, match="outside"):
        interpolate_linear(t, np.zeros(2), np.array([25]))


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 20), q=st.integers(1, 30))
def test_slerp_properties(seed, n, q):
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(1, 10**9, size=n)).astype(np.int64)
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    # at the sample times: the samples themselves (up to sign)
    at = slerp(t, quats, t)
    np.testing.assert_allclose(np.abs(np.sum(at * quats, axis=1)), 1.0, atol=1e-9)
    # anywhere inside: unit length, and on the shorter arc between the neighbours
    tq = np.sort(rng.integers(t[0], t[-1] + 1, size=q))
    out = slerp(t, quats, tq)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-9)
    i = np.clip(np.searchsorted(t, tq, side="right") - 1, 0, n - 2)
    gap = np.arccos(np.clip(np.abs(np.sum(quats[i] * quats[i + 1], axis=1)), 0, 1))
    to_left = np.arccos(np.clip(np.abs(np.sum(out * quats[i], axis=1)), 0, 1))
    to_right = np.arccos(np.clip(np.abs(np.sum(out * quats[i + 1], axis=1)), 0, 1))
    np.testing.assert_allclose(to_left + to_right, gap, atol=1e-6)
