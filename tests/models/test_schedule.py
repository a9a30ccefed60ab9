"""The training schedule: one rule of the training data for the steps, the warm-up and the validation interval."""

import logging

import numpy as np
import pytest

from cnep.models.config import CNEPConfig, TrainConfig
from cnep.models.schedule import (
    BASE_STEPS,
    DRAWS_PER_DEMONSTRATION,
    MAX_VAL_EVERY,
    MAX_WARMUP,
    SCHEDULED,
    schedule_of,
    scheduled,
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
    given = TrainConfig(steps=5, warmup_steps=1, val_every=2)
    assert scheduled(given, 10_000) == given


def test_a_warm_up_longer_than_the_run_is_warned_about(caplog):
    with caplog.at_level(logging.WARNING, logger="cnep.models.schedule"):
        schedule_of(TrainConfig(steps=10, warmup_steps=10), 5)
    assert "never reaches its peak" in caplog.text


def test_the_record_names_its_input_values_and_what_was_given():
    record = schedule_of(TrainConfig(val_every=7), 40).to_dict()
    assert record == {
        "inputs": {"demonstrations": 40, "batch_size": 32},
        "steps": BASE_STEPS,
        "warmup_steps": MAX_WARMUP,
        "val_every": 7,
        "given": ["val_every"],
    }


def test_a_trainer_fills_the_schedule_from_the_demonstrations_it_trains_on():
    trajectories = [np.linspace(0, 1, 12, dtype=np.float32)[:, None] + i for i in range(10)]
    trainer, split = prepare_fit(trajectories, CNEPConfig(encoder_widths=(8,), expert_widths=(8,)), TrainConfig())
    assert split["n_train"] == 8  # a fifth held out
    assert all(getattr(trainer.cfg, name) == getattr(schedule_of(TrainConfig(), 8), name) for name in SCHEDULED)


@pytest.mark.parametrize("name", SCHEDULED)
def test_a_scheduled_setting_defaults_to_the_schedule(name):
    assert getattr(TrainConfig(), name) is None
