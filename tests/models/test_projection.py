"""`CNEPConfig.feature_components`: the encoder reads the observed-only columns as their principal components."""

import dataclasses

import numpy as np
import pytest
import torch

from cnep.models.cnep import CNEP
from cnep.models.config import CNEPConfig, TrainConfig
from cnep.models.errors import ConfigError
from cnep.models.normaliser import Moments
from cnep.models.train import build_model, prepare_fit
from tests.models.factories import feature_config, feature_trajectories, tiny_config


def contexts(model: CNEP, trajectories: list[np.ndarray]) -> torch.Tensor:
    """Every row of `trajectories` as a context (R, 1 + obs_dim): t = 0, then its normalised observed columns."""
    rows = torch.from_numpy(np.concatenate(trajectories))
    values = model.normaliser.normalise(rows, model.obs_columns)
    return torch.cat([torch.zeros(len(rows), 1), values], dim=-1)


def test_the_components_are_the_training_rows_principal_coordinates_at_unit_variance():
    trajectories = feature_trajectories()
    model = build_model(feature_config(features=6, components=3), trajectories, seed=0)
    context = contexts(model, trajectories)
    projected = model.project(context).double()  # (R, t + 2 predicted columns + 3 components)
    assert projected.shape == (len(context), 6) and model.context_width == 6
    assert torch.equal(projected[:, :3], context[:, [0, 7, 8]].double())  # t and the predicted columns, as they were
    components = projected[:, 3:].numpy()
    np.testing.assert_allclose(np.cov(components.T, bias=True), np.eye(3), atol=1e-4)  # uncorrelated, unit variance
    raw = np.concatenate(trajectories)[:, :6].astype(np.float64)
    standardised = (raw - raw.mean(0)) / raw.std(0)  # every feature alike, whatever its spread
    _, _, vt = np.linalg.svd(standardised, full_matrices=False)
    directions = vt[:3] * np.sign(vt[:3][np.arange(3), np.abs(vt[:3]).argmax(1)])[:, None]  # largest entry positive
    expected = standardised @ directions.T
    np.testing.assert_allclose(components, expected / expected.std(0), atol=1e-3)


def test_the_projection_from_summed_moments_of_shares_is_the_one_from_the_trajectories_in_any_order():
    config, trajectories = feature_config(), feature_trajectories()
    co = config.projected_columns
    assert co == tuple(range(6))
    shares = Moments.total(Moments.of(t, co) for t in trajectories[:2]) + Moments.total(
        Moments.of(t, co) for t in trajectories[2:]
    )
    whole = build_model(config, trajectories, seed=0).feature_projection
    for fitted in (build_model(config, shares, seed=0), build_model(config, trajectories[::-1], seed=0)):
        torch.testing.assert_close(fitted.feature_projection, whole, rtol=1e-6, atol=1e-6)  # signs included
    with pytest.raises(ConfigError, match="scatter matrix of the 6 columns"):
        build_model(config, Moments.total(Moments.of(t) for t in trajectories), seed=0)


def test_each_direction_is_signed_by_its_largest_entry():
    model = build_model(feature_config(components=4), feature_trajectories(seed=1), seed=0)
    directions = model.feature_projection  # (6, 4), each column a direction over its component's std
    largest = directions.abs().argmax(0)
    assert (directions[largest, torch.arange(4)] > 0).all()


def test_k_out_of_range_or_without_observed_only_columns_is_one_clear_error():
    for bad in (-3, True, 2.5):
        with pytest.raises(ConfigError, match="feature_components must be a whole number >= 0"):
            CNEPConfig(feature_components=bad)
    with pytest.raises(ConfigError, match="at most the 6 columns the model observes but does not predict, got 7"):
        CNEP(feature_config(features=6, components=7))
    predicts_all = dataclasses.replace(tiny_config(query_dim=0), columns=CNEPConfig().columns, feature_components=1)
    with pytest.raises(ConfigError, match="this model predicts every column it observes"):
        CNEP(predicts_all)
    CNEP(feature_config(features=6, components=6))  # every column as a component: allowed
    CNEP(dataclasses.replace(predicts_all, feature_components=0))  # 0: every column as it is, whatever the columns


def test_without_components_the_model_is_built_as_before_and_old_configs_load_so():
    plain, projected = CNEP(feature_config(components=None)), CNEP(feature_config(components=3))
    assert set(CNEP(feature_config(components=0)).state_dict()) == set(plain.state_dict())  # 0: every column, given
    assert CNEPConfig().feature_components is None
    assert set(projected.state_dict()) == set(plain.state_dict()) | {"feature_projection"}
    assert plain.encoder[0].weight.shape == (16, 5 + 8) and projected.encoder[0].weight.shape == (16, 5 + 2 + 3)
    context = torch.rand(4, 9)
    assert plain.project(context) is context  # read as it is
    old = {k: v for k, v in feature_config(components=None).to_dict().items() if k != "feature_components"}
    assert CNEPConfig.from_dict(old) == feature_config(components=None)


def test_dropout_and_decay_act_on_the_components():
    cfg = TrainConfig(steps=10, warmup_steps=2, val_every=10, batch_size=8, observed_only_dropout=0.5)
    trainer, _ = prepare_fit(feature_trajectories(), feature_config(components=3), cfg)
    # encoder inputs: t's 1 + 2 x 2 time features, the 2 predicted columns, then the 3 components
    assert trainer.dropped == trainer.decayed == trainer.model.observed_only_inputs() == [(7, 10)]
    batch = trainer.next_batch()
    assert batch.keep.shape == (*batch.obs.shape[:-1], 3)
    full, dropped = trainer.model.encoder_inputs(batch.obs), trainer.model.encoder_inputs(batch.obs, batch.keep)
    assert torch.equal(dropped[..., :7], full[..., :7]) and torch.equal(dropped[..., 7:], full[..., 7:] * batch.keep)
    before = trainer.model.encoder[0].weight.detach().clone()
    trainer.train_step()
    assert not torch.equal(trainer.model.encoder[0].weight[:, 7:10], before[:, 7:10])
