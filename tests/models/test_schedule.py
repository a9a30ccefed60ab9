"""The training schedule: one rule of the training data for the steps, the warm-up, the validation interval and the
feature components."""

import logging

import numpy as np
import pytest

from cnep.models.config import CNEPConfig, ColumnRoles, ConfigError, TrainConfig
from cnep.models.schedule import (
    BASE_STEPS,
    DRAWS_PER_DEMONSTRATION,
    FEW_DEMONSTRATIONS,
    MAX_VAL_EVERY,
    MAX_WARMUP,
    ONLINE_SHARE,
    SCHEDULED,
    components_for,
    online_contexts_for,
    schedule_of,
    scheduled,
    with_components,
)
from cnep.models.train import prepare_fit


def test_the_steps_grow_with_the_data_past_the_base():
    small, large = schedule_of(TrainConfig(), 2), schedule_of(TrainConfig(), 1_000)
    assert small.steps == BASE_STEPS
    assert large.steps >= DRAWS_PER_DEMONSTRATION * 1_000 / 32 > BASE_STEPS and large.steps % 100 == 0
    assert (large.warmup_steps, large.val_every) == (MAX_WARMUP, MAX_VAL_EVERY)
    more_processes = schedule_of(TrainConfig(), 1_000, world_size=4)  # four times the samples a step
    assert more_processes.steps < large.steps and more_processes.batch_size == 4 * 32


def test_given_values_win_and_the_rest_follow_the_steps():
    made = schedule_of(TrainConfig(steps=60), 500)
    assert (made.steps, made.warmup_steps, made.val_every, made.given) == (60, 30, 7, ("steps",))
    made = schedule_of(TrainConfig(warmup_steps=10, val_every=3), 500)
    assert (made.warmup_steps, made.val_every, made.given) == (10, 3, ("warmup_steps", "val_every"))
    given = TrainConfig(steps=5, warmup_steps=1, val_every=2, online_contexts=0.5)
    assert scheduled(given, 10_000) == given


def test_a_warm_up_longer_than_the_run_is_warned_about(caplog):
    with caplog.at_level(logging.WARNING, logger="cnep.models.schedule"):
        schedule_of(TrainConfig(steps=10, warmup_steps=10), 5)
    assert "never reaches its peak" in caplog.text


def test_the_record_names_its_input_values_and_what_was_given():
    record = schedule_of(TrainConfig(val_every=7), 40).to_dict()
    assert record == {
        "inputs": {"demonstrations": 40, "batch_size": 32, "scenes": 40},
        "steps": BASE_STEPS,
        "warmup_steps": MAX_WARMUP,
        "val_every": 7,
        "feature_components": None,
        "online_contexts": 0.0,
        "given": ["val_every"],
    }


# A model that predicts the pose and gripper (8 columns) and observes 1280 image features besides.
IMAGES = ColumnRoles(width=1288, observed=((0, 1288),), query=((1280, 1288),), predicted=((1280, 1288),))


def test_fewer_demonstrations_than_features_read_as_many_components():
    few = FEW_DEMONSTRATIONS
    assert [components_for(1280, n) for n in (1, 8, few - 1, few, 5_000)] == [1, 8, few - 1, None, None]
    assert components_for(0, 8) is None  # a motion-only model observes nothing it does not predict
    assert components_for(6, 8) is None and components_for(9, 8) == 8
    model = CNEPConfig(columns=IMAGES)
    assert with_components(model, 40).feature_components == 40
    assert with_components(CNEPConfig(columns=IMAGES, feature_components=16), 40).feature_components == 16
    record = schedule_of(TrainConfig(), 40, model=model).to_dict()
    assert (record["feature_components"], record["given"]) == (40, [])
    record = schedule_of(TrainConfig(), 40, model=CNEPConfig(columns=IMAGES, feature_components=16)).to_dict()
    assert (record["feature_components"], record["given"]) == (16, ["feature_components"])
    # views of the demonstrations' frames are more scenes: 40 demonstrations seen in 80 read every column
    record = schedule_of(TrainConfig(), 40, model=model, scenes=80).to_dict()
    assert (record["inputs"]["scenes"], record["feature_components"], record["given"]) == (80, None, [])
    assert record["steps"] == schedule_of(TrainConfig(), 40).steps  # the steps follow the demonstrations alone


def test_a_model_that_reads_a_camera_trains_on_its_policys_contexts_and_a_motion_model_on_the_papers():
    assert online_contexts_for(1280) == ONLINE_SHARE > 0 and online_contexts_for(0) == 0.0
    record = schedule_of(TrainConfig(), 40, model=CNEPConfig(columns=IMAGES)).to_dict()
    assert (record["online_contexts"], record["given"]) == (ONLINE_SHARE, [])
    assert scheduled(TrainConfig(), 40, model=CNEPConfig(columns=IMAGES)).online_contexts == ONLINE_SHARE
    assert scheduled(TrainConfig(), 40).online_contexts == 0.0  # observes only what it predicts
    record = schedule_of(TrainConfig(online_contexts=0.25), 40, model=CNEPConfig(columns=IMAGES)).to_dict()
    assert (record["online_contexts"], record["given"]) == (0.25, ["online_contexts"])


def test_a_trainer_reads_the_features_as_components_of_its_demonstrations():
    rng = np.random.default_rng(0)
    features = [np.hstack([rng.normal(size=(12, 20)), np.linspace(0, 1, 12)[:, None] + i]) for i in range(10)]
    roles = ColumnRoles(width=21, observed=((0, 21),), query=((20, 21),), predicted=((20, 21),))
    trainer, split = prepare_fit(
        features, CNEPConfig(columns=roles, encoder_widths=(8,), expert_widths=(8,)), TrainConfig()
    )
    assert trainer.model.config.feature_components == split["n_train"] == 8
    assert trainer.model.feature_projection.shape == (20, 8)


def test_zero_components_read_every_feature_whatever_the_demonstrations():
    rng = np.random.default_rng(0)
    features = [np.hstack([rng.normal(size=(12, 20)), np.linspace(0, 1, 12)[:, None] + i]) for i in range(10)]
    roles = ColumnRoles(width=21, observed=((0, 21),), query=((20, 21),), predicted=((20, 21),))
    config = CNEPConfig(columns=roles, encoder_widths=(8,), expert_widths=(8,), feature_components=0)
    trainer, _ = prepare_fit(features, config, TrainConfig())
    assert trainer.model.config.feature_components == 0
    assert trainer.model.context_width == 1 + roles.obs_dim and not hasattr(trainer.model, "feature_projection")
    record = schedule_of(TrainConfig(), 8, model=config).to_dict()
    assert (record["feature_components"], record["given"]) == (0, ["feature_components"])
    with pytest.raises(ConfigError, match="whole number >= 0"):
        CNEPConfig(feature_components=-1)


def test_a_trainer_fills_the_schedule_from_the_demonstrations_it_trains_on():
    trajectories = [np.linspace(0, 1, 12, dtype=np.float32)[:, None] + i for i in range(10)]
    trainer, split = prepare_fit(trajectories, CNEPConfig(encoder_widths=(8,), expert_widths=(8,)), TrainConfig())
    assert split["n_train"] == 8  # a fifth held out
    assert all(getattr(trainer.cfg, name) == getattr(schedule_of(TrainConfig(), 8), name) for name in SCHEDULED)


@pytest.mark.parametrize("name", SCHEDULED)
def test_a_scheduled_setting_defaults_to_the_schedule(name):
    assert getattr(TrainConfig(), name) is None
