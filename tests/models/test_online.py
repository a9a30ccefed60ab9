"""Online conditioning: the incremental (running-sum) conditioner gives exactly what re-encoding the
whole conditioning set gives, follows its policy, and reports every expert switch."""

import numpy as np
import pytest
import torch

from cnep.models.cnep import CNEP
from cnep.models.errors import ConfigError
from cnep.models.online import ConditioningPolicy, OnlineConditioner
from cnep.runtime import PolicyError
from tests.models.factories import tiny_config


def random_model(seed: int = 0, n_experts: int = 3) -> tuple[CNEP, np.ndarray]:
    """An untrained model with a non-uniform gate and a fitted normaliser, and a (60, 5) trajectory."""
    torch.manual_seed(seed)
    model = CNEP(tiny_config(n_experts=n_experts)).eval()
    rng = np.random.default_rng(seed)
    traj = np.cumsum(rng.normal(size=(60, 5)), axis=0).astype(np.float32)  # a random walk: the gate moves
    with torch.no_grad():
        model.gate.weight.mul_(20.0)  # a confident gate, so argmax changes are clear-cut
    model.normaliser.fit([traj])
    return model, traj


def expected_set(k: int, policy: ConditioningPolicy) -> list[int]:
    anchors = list(range(min(k + 1, policy.anchors)))
    recent = range(max(policy.anchors, k + 1 - policy.window), k + 1)
    return anchors + list(recent)


@pytest.mark.parametrize(
    "policy",
    [
        ConditioningPolicy(window=4, anchors=1, switch_margin=0.0),  # the active expert is the gate's argmax,
        ConditioningPolicy(window=7, anchors=0, switch_margin=0.0),  # as the model's own generate picks it
        ConditioningPolicy(window=1, anchors=3, switch_margin=0.0),
    ],
)
def test_incremental_conditioning_equals_conditioning_on_the_whole_set(policy):
    model, traj = random_model()
    T = len(traj)
    online = OnlineConditioner(model, horizon=T, policy=policy)
    obs_cols, q_cols = model.obs_columns.numpy(), model.query_columns.numpy()
    for k in range(T):
        out = online.step(traj[k])
        idx = expected_set(k, policy)
        assert online.n_conditioning == len(idx)
        t_next = min((k + 1) / (T - 1), 1.0)
        ref = model.generate(np.array(idx) / (T - 1), traj[idx][:, obs_cols], np.array([t_next]), traj[[k]][:, q_cols])
        np.testing.assert_allclose(out.gate, ref.gate, rtol=1e-5, atol=1e-6)
        assert out.expert == ref.expert
        np.testing.assert_allclose(out.next_mean, ref.mean[0], rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(out.next_std, ref.std[0], rtol=1e-4, atol=1e-5)


def test_switches_are_exactly_the_argmax_changes():
    model, _ = random_model()
    rng = np.random.default_rng(0)
    blocks = np.repeat([3.0, -3.0, 3.0, -3.0], 15)[:, None]  # the observations jump between two regions
    traj = (blocks + 0.1 * rng.normal(size=(60, 5))).astype(np.float32)
    model.normaliser.fit([traj])
    online = OnlineConditioner(model, horizon=len(traj), policy=ConditioningPolicy(window=2, anchors=0))
    steps = [online.step(row, timestamp_ns=1000 * k) for k, row in enumerate(traj)]
    experts = np.array([s.expert for s in steps])
    changes = np.flatnonzero(experts[1:] != experts[:-1]) + 1
    assert len(changes) >= 2, "jumping observations should make the gate switch"
    switches = [s.switch for s in steps if s.switch is not None]
    assert [s.step for s in switches] == changes.tolist()
    for s in switches:
        assert (s.from_expert, s.to_expert) == (experts[s.step - 1], experts[s.step])
        assert s.timestamp_ns == 1000 * s.step and s.t == pytest.approx(s.step / (len(traj) - 1))
        np.testing.assert_array_equal(s.gate, steps[s.step].gate)
    assert all(np.isclose(s.gate.sum(), 1.0, atol=1e-6) for s in steps)


def test_predict_the_remaining_trajectory_for_all_experts_or_the_active_one():
    model, traj = random_model()
    online = OnlineConditioner(model, horizon=len(traj))
    with pytest.raises(ConfigError, match="step"):
        online.predict(np.array([0.5]))
    for row in traj[:10]:
        online.step(row)
    query_t = online.time_of(np.arange(10, len(traj)))
    means, stds = online.predict(query_t, all_experts=True)
    assert means.shape == stds.shape == (3, len(traj) - 10, 2)
    mean, std = online.predict(query_t)
    np.testing.assert_array_equal(mean, means[online.expert])
    assert (std > 0).all()


def test_reset_starts_a_new_episode():
    model, traj = random_model()
    online = OnlineConditioner(model, horizon=len(traj))
    first = [online.step(row).gate for row in traj[:5]]
    online.reset()
    again = [online.step(row).gate for row in traj[:5]]
    np.testing.assert_array_equal(np.array(first), np.array(again))
    assert online.step(traj[5]).step == 5


def test_bad_inputs_are_refused():
    model, traj = random_model()
    with pytest.raises(PolicyError, match="window"):
        ConditioningPolicy(window=0)
    with pytest.raises(PolicyError, match="anchors"):
        ConditioningPolicy(anchors=-1)
    with pytest.raises(ConfigError, match="horizon"):
        OnlineConditioner(model, horizon=1)
    with pytest.raises(ConfigError, match=r"\(5,\) row"):
        OnlineConditioner(model, horizon=10).step(np.zeros(4))
