import numpy as np
import pytest
import torch

from cnep.models.cnep import CNEP
from cnep.models.config import CNEPConfig, TrainConfig
from cnep.models.errors import ConfigError
from tests.models.factories import random_inputs, tiny_config


@pytest.fixture
def model():
    torch.manual_seed(0)
    return CNEP(tiny_config()).eval()


def test_output_shapes_and_gate_sums_to_one(model):
    obs, mask, query = random_inputs(model.config, B=4, N=5, M=6)
    mean, std, gate = model(obs, mask, query)
    assert mean.shape == std.shape == (4, 3, 6, 2)
    assert gate.shape == (4, 3)
    torch.testing.assert_close(gate.sum(-1), torch.ones(4))
    assert (std >= model.config.min_std).all()


def test_padding_never_changes_the_result(model):
    obs, mask, query = random_inputs(model.config, B=2, N=3, M=4)
    padded = torch.cat([obs, 1e3 * torch.randn(2, 4, obs.shape[-1])], dim=1)  # junk in the padding
    padded_mask = torch.cat([mask, torch.zeros(2, 4, dtype=torch.bool)], dim=1)
    for a, b in zip(model(obs, mask, query), model(padded, padded_mask, query)):
        torch.testing.assert_close(a, b)


def test_samples_do_not_depend_on_the_batch_they_are_in(model):
    obs, mask, query = random_inputs(model.config, B=5, N=4, M=3)
    together = model(obs, mask, query)
    for i in range(5):
        alone = model(obs[i : i + 1], mask[i : i + 1], query[i : i + 1])
        for a, b in zip(together, alone):
            torch.testing.assert_close(a[i : i + 1], b, rtol=1e-5, atol=1e-6)


def test_batched_experts_match_each_expert_run_alone(model):
    obs, mask, query = random_inputs(model.config, B=3, N=4, M=5)
    r, query = model.encode(obs, mask), model.embed_time(query)
    out = model.experts(r, query)  # (d, B*M, 2dy)
    ex = model.experts
    w0 = ex.first_r.shape[1] // ex.d
    for e in range(ex.d):  # reference: one plain MLP per expert
        cols = slice(e * w0, (e + 1) * w0)
        x = torch.cat([r.unsqueeze(1).expand(-1, 5, -1), query], -1).reshape(15, -1)
        h = x @ torch.cat([ex.first_r[:, cols], ex.first_q[:, cols]]) + ex.first_b[cols]
        for w, b in zip(ex.weights, ex.biases):
            h = torch.relu(h) @ w[e] + b[e]
        torch.testing.assert_close(out[e], h, rtol=1e-5, atol=1e-5)


def test_any_batch_size_and_lengths(model):
    for B, N, M in [(1, 1, 1), (7, 10, 3), (2, 1, 200)]:
        obs, mask, query = random_inputs(model.config, B=B, N=N, M=M)
        mean, _, gate = model(obs, mask, query)
        assert mean.shape == (B, 3, M, 2) and gate.shape == (B, 3)


def test_generate_returns_winner_or_mixture_in_data_units():
    config = tiny_config(query_dim=0)
    torch.manual_seed(1)
    m = CNEP(config).eval()
    m.normaliser.loc.copy_(torch.tensor([1.0, 2.0, 10.0, -5.0]))
    m.normaliser.scale.copy_(torch.tensor([2.0, 3.0, 4.0, 0.5]))
    obs_t, obs_v, q_t = np.array([0.0, 0.5]), np.array([[1.0, 2.0], [3.0, 4.0]]), np.linspace(0, 1, 7)
    wta = m.generate(obs_t, obs_v, q_t)
    moe = m.generate(obs_t, obs_v, q_t, mixture=True)
    assert wta.mean.shape == (7, 2) and wta.expert_means.shape == (3, 7, 2)
    np.testing.assert_allclose(wta.mean, wta.expert_means[wta.expert])
    np.testing.assert_allclose(moe.mean, np.einsum("e,emk->mk", moe.gate, moe.expert_means), rtol=1e-5, atol=1e-5)
    # the normaliser is applied on the way in and undone on the way out
    raw_mean, _, _ = m(
        m.prepare(torch.tensor(obs_t, dtype=torch.float32), torch.tensor(obs_v), m.obs_columns)[None],
        torch.ones(1, 2, dtype=torch.bool),
        torch.tensor(q_t, dtype=torch.float32)[None, :, None],
    )
    np.testing.assert_allclose(wta.expert_means, raw_mean[0].detach().numpy() * [4.0, 0.5] + [10.0, -5.0], rtol=1e-5)


def test_generate_requires_query_values_when_the_layout_has_them(model):
    with pytest.raises(ConfigError, match="query_values"):
        model.generate(np.zeros(1), np.zeros((1, 2)), np.zeros(3))


def test_cnmp_is_one_expert_without_entropy_terms():
    cfg = CNEPConfig(n_experts=1)
    assert (cfg.a_batch, cfg.a_ind) == (0.0, 0.0)
    mean, _, gate = CNEP(cfg)(torch.rand(2, 3, 2), torch.ones(2, 3, dtype=torch.bool), torch.rand(2, 4, 1))
    assert mean.shape == (2, 1, 4, 1)
    torch.testing.assert_close(gate, torch.ones(2, 1))


@pytest.mark.parametrize(
    ("d", "expected"), [(2, (16.81, 10.672, 7.553)), (4, (33.62, 5.336, 3.7765)), (8, (67.24, 3.5573, 2.5177))]
)
def test_default_coefficients_are_the_authors_rescaled_with_d(d, expected):
    cfg = CNEPConfig(n_experts=d)
    np.testing.assert_allclose((cfg.a_rec, cfg.a_batch, cfg.a_ind), expected, rtol=1e-4)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_experts": 0}, "n_experts"),
        ({"min_std": 0.0}, "min_std"),
        ({"a_batch": -1.0}, "a_batch"),
        ({"columns": {"width": 3, "observed": ((0, 4),)}}, "width=3"),
    ],
)
def test_config_errors_state_the_rule_and_the_value(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        CNEPConfig(**kwargs)


def test_train_config_rejects_bad_values():
    with pytest.raises(ConfigError, match="gate_freeze_fraction"):
        TrainConfig(gate_freeze_fraction=1.5)
    with pytest.raises(ConfigError, match="steps"):
        TrainConfig(steps=0)
    with pytest.raises(ConfigError, match="obs_noise must be >= 0"):
        TrainConfig(obs_noise=-0.1)
    with pytest.raises(ConfigError, match="observed_only_decay must be >= 0"):
        TrainConfig(observed_only_decay=-1.0)
    with pytest.raises(ConfigError, match="first_steps_fraction must be in"):
        TrainConfig(first_steps_fraction=1.5)
    with pytest.raises(ConfigError, match="first_steps_max >= 1"):
        TrainConfig(first_steps_max=0)
    with pytest.raises(ConfigError, match=r"nll_beta must be in \[0, 1\].*got 1.5"):
        TrainConfig(nll_beta=1.5)


def test_config_round_trips_through_a_dict():
    cfg = tiny_config()
    assert CNEPConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ConfigError, match="Unknown CNEPConfig field"):
        CNEPConfig.from_dict({**cfg.to_dict(), "n_heads": 3})


def test_assignment_is_checked_and_old_configs_load_with_the_papers_term():
    assert CNEPConfig().assignment == "bounded"  # commits where behaviours share a context; "paper" reproduces it
    mixture = CNEPConfig(assignment="mixture")
    assert CNEPConfig.from_dict(mixture.to_dict()) == mixture
    old = {k: v for k, v in CNEPConfig(assignment="mixture").to_dict().items() if k != "assignment"}
    assert CNEPConfig.from_dict(old).assignment == "paper"  # written before the field existed
    with pytest.raises(ConfigError, match="assignment must be one of paper, mixture"):
        CNEPConfig(assignment="em")
