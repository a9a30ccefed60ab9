"""The runtime's conditioner: its running sum is the mean over exactly the policy's set, one encoding per step."""

import numpy as np
import pytest

from cnep.runtime import Columns, Conditioner, ConditioningPolicy, PolicyError
from tests.runtime.fakes import LinearNetwork, ScriptedNetwork


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
    with pytest.raises(PolicyError, match="first_expert"):
        ConditioningPolicy(first_expert="random")
    with pytest.raises(PolicyError, match="switch_margin"):
        ConditioningPolicy(switch_margin=1.0)
    with pytest.raises(PolicyError, match="switch_window"):
        ConditioningPolicy(switch_window=-1)
    with pytest.raises(PolicyError, match="do not fit"):
        Columns(((0, 9),), (), ((0, 1),), np.zeros(3), np.ones(3))
    with pytest.raises(PolicyError, match="positive scale"):
        Columns(((0, 1),), (), ((0, 1),), np.zeros(3), np.zeros(3))


def experts_of(gates, policy: ConditioningPolicy, seed: int | None = None) -> tuple[list[int], list[int]]:
    """The active expert at each step of a scripted gate, and the steps where it switched."""
    columns = Columns(((0, 2),), (), ((2, 3),), np.zeros(3), np.ones(3))
    conditioner = Conditioner(ScriptedNetwork(gates, obs_dim=2, out_dim=1), columns, policy)
    conditioner.reset(seed)
    steps = [conditioner.step(np.ones(3, np.float32), k / 10, np.array([1.0])) for k in range(len(gates))]
    return [s[1] for s in steps], [k for k, s in enumerate(steps) if s[2] is not None]


WAVERING = [[0.6, 0.4], [0.45, 0.55], [0.55, 0.45], [0.4, 0.6], [0.6, 0.4], [0.1, 0.9], [0.2, 0.8], [0.6, 0.4]]


def test_without_a_margin_the_active_expert_is_the_gates_argmax():
    experts, switches = experts_of(WAVERING, ConditioningPolicy(switch_margin=0.0))
    assert experts == [int(np.argmax(g)) for g in WAVERING] and switches == [1, 2, 3, 4, 5, 7]


def test_a_margin_keeps_the_expert_through_a_wavering_gate_and_switches_when_the_gate_moves():
    for window in (0, 3):  # the active expert's probability never falls by the margin over 3 steps here
        experts, switches = experts_of(WAVERING, ConditioningPolicy(switch_margin=0.3, switch_window=window))
        assert experts == [0, 0, 0, 0, 0, 1, 1, 1] and switches == [5]  # 0.6 - 0.4 at the end is not enough


SLIDING = [[0.95, 0.05], [0.9, 0.1], [0.8, 0.2], [0.65, 0.35], [0.48, 0.52], [0.3, 0.7], [0.15, 0.85]]


def test_a_steady_slide_switches_where_the_two_cross_and_the_margin_alone_later():
    assert experts_of(SLIDING, ConditioningPolicy(switch_margin=0.0))[1] == [4]  # the argmax
    assert experts_of(SLIDING, ConditioningPolicy(switch_margin=0.3, switch_window=3))[1] == [4]  # 0.8 -> 0.48
    assert experts_of(SLIDING, ConditioningPolicy(switch_margin=0.3, switch_window=0))[1] == [5]  # lead 0.4


def test_sample_draws_the_first_expert_from_the_gate_and_the_margin_keeps_it():
    gate = [[0.5, 0.3, 0.2]]
    policy = ConditioningPolicy(first_expert="sample", switch_margin=0.4)
    firsts = [experts_of(gate * 5, policy, seed)[0] for seed in range(600)]
    assert all(len(set(run)) == 1 for run in firsts)  # each episode keeps the expert it drew
    share = np.bincount([run[0] for run in firsts], minlength=3) / len(firsts)
    np.testing.assert_allclose(share, gate[0], atol=0.06)
    assert experts_of(gate, policy, 7) == experts_of(gate, policy, 7)  # the same seed, the same draw
    assert experts_of(gate, ConditioningPolicy(), 7)[0] == [0]  # argmax ignores the seed
    unkept = ConditioningPolicy(first_expert="sample", switch_margin=0.0)
    for seed in range(10):  # without a margin, a drawn expert gives way to the argmax at the next step
        experts, switches = experts_of(gate * 3, unkept, seed)
        assert experts[1:] == [0, 0] and switches == ([] if experts[0] == 0 else [1])
