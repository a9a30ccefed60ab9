"""The runtime's conditioner: its running sum is the mean over exactly the policy's set, one encoding per step."""

import numpy as np
import pytest

from cnep.runtime import Columns, Conditioner, ConditioningPolicy, PolicyError
from tests.runtime.fakes import LinearNetwork


class Recording(LinearNetwork):
    """Remembers the latent of every decode."""

    def decode(self, r, query):
        self.latents = [*getattr(self, "latents", []), r[0].copy()]
        return super().decode(r, query)


def expected_set(k: int, policy: ConditioningPolicy) -> list[int]:
    anchors = list(range(min(k + 1, policy.anchors)))
    return anchors + list(range(max(policy.anchors, k + 1 - policy.window), k + 1))


@pytest.mark.parametrize("policy", [ConditioningPolicy(4, 1), ConditioningPolicy(7, 0), ConditioningPolicy(1, 3)])
def test_the_latent_is_the_mean_encoding_of_the_policys_set(policy):
    rng = np.random.default_rng(0)
    rows = rng.normal(size=(30, 5)).astype(np.float32)
    columns = Columns(((0, 3),), ((3, 4),), ((4, 5),), rng.normal(size=5), rng.uniform(0.5, 2, 5))
    network = Recording(obs_dim=3, query_dim=1, out_dim=1)
    conditioner = Conditioner(network, columns, policy)
    obs = np.concatenate([np.zeros((30, 1)), (rows[:, :3] - columns.loc[:3]) / columns.scale[:3]], axis=1)
    obs[:, 0] = np.arange(30) / 29
    for k in range(30):
        gate, expert, _, mean, std = conditioner.step(rows[k], k / 29, np.array([0.5, 1.0]))
        idx = expected_set(k, policy)
        assert conditioner.n_conditioning == len(idx)
        np.testing.assert_allclose(network.latents[-1], network.encode(obs[idx].astype(np.float32)).mean(0), atol=1e-6)
        assert mean.shape == std.shape == (2, 1) and expert == int(gate.argmax())
    assert network.encoded == 30 + sum(len(expected_set(k, policy)) for k in range(30))  # one per step + the checks


def test_predict_needs_a_step_and_gives_every_expert_on_request():
    columns = Columns(((0, 2),), (), ((2, 3),), np.zeros(3), np.ones(3))
    conditioner = Conditioner(LinearNetwork(2, 0, 1), columns)
    with pytest.raises(PolicyError, match="step"):
        conditioner.predict(np.array([0.5]))
    conditioner.step(np.ones(3, np.float32), 0.0, np.array([0.1]))
    means, stds = conditioner.predict(np.linspace(0, 1, 4), all_experts=True)
    mean, _ = conditioner.predict(np.linspace(0, 1, 4))
    assert means.shape == stds.shape == (3, 4, 1)
    np.testing.assert_array_equal(mean, means[conditioner.expert])


def test_bad_columns_and_policies_are_refused():
    with pytest.raises(PolicyError, match="window"):
        ConditioningPolicy(window=0)
    with pytest.raises(PolicyError, match="anchors"):
        ConditioningPolicy(anchors=-1)
    with pytest.raises(PolicyError, match="do not fit"):
        Columns(((0, 9),), (), ((0, 1),), np.zeros(3), np.ones(3))
    with pytest.raises(PolicyError, match="positive scale"):
        Columns(((0, 1),), (), ((0, 1),), np.zeros(3), np.zeros(3))
