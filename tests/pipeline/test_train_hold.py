"""Demonstrations whose recording stops as the gripper changes are trained held at their last step."""

import logging

import numpy as np
import pytest

from cnep.models import read_checkpoint_config
from cnep.pipeline.train.hold import END_HOLD_SHARE, held_steps
from cnep.pipeline.train.stage import train
from cnep.recordings import write_trajectory
from cnep.runtime.gripper import GripperCommand
from tests.pipeline.test_train import stage_config
from tests.recordings.factories import trajectory_factory

pytestmark = pytest.mark.usefixtures("one_thread")

OPENING = GripperCommand.from_levels(0.017, 0.040)  # a measured opening: closed on an object reads its width


def pick(steps: int, open_at_end: int) -> np.ndarray:
    """A pick-and-place gripper of `steps` (T,): open, closed from a third of the way, open again for its last
    `open_at_end` steps."""
    gripper = np.full(steps, 0.040)
    gripper[steps // 3 : steps - open_at_end] = 0.017
    return gripper


def test_a_recording_that_stops_as_the_gripper_opens_is_held_until_the_open_state_lasts_the_share():
    assert held_steps(pick(65, 1), OPENING) == int(np.ceil(END_HOLD_SHARE * 65)) - 1
    assert held_steps(pick(80, 3), OPENING) == int(np.ceil(END_HOLD_SHARE * 80)) - 3
    assert held_steps(pick(80, 13), OPENING) == 0  # it recorded the withdrawal: trained as it is
    assert held_steps(np.full(40, 0.040), OPENING) == 0  # a gripper that never changes
    grasp = np.full(60, 0.040)  # stops as the gripper closes: the closed state is held
    grasp[-2:] = 0.017
    assert held_steps(grasp, OPENING) == int(np.ceil(END_HOLD_SHARE * 60)) - 2


def test_the_train_stage_records_each_held_demonstration_and_its_time_base_counts_the_held_steps(tmp_path, caplog):
    folder, lengths, ends = tmp_path / "picks", (30, 40, 36), (1, 20, 2)  # the second recorded its withdrawal
    folder.mkdir()
    for k, (steps, open_at_end) in enumerate(zip(lengths, ends)):
        traj = trajectory_factory(steps, seed=k)
        traj.data[:, -1] = pick(steps, open_at_end)
        write_trajectory(folder / f"demo-{k}.mcap", traj)
    with caplog.at_level(logging.INFO, logger="cnep.pipeline.train.stage"):
        out = train(stage_config([folder], tmp_path / "ckpt", steps=5, val_fraction=0.34))
    config = read_checkpoint_config(out)
    held = [f.get("held_steps", 0) for f in sorted(config["files"], key=lambda f: f["path"])]
    expected = [held_steps(pick(n, e), OPENING) for n, e in zip(lengths, ends)]
    assert held == expected and expected[0] > 0 and expected[1] == 0
    assert "2 demonstration(s) end less than 10% of their steps after their gripper's last change" in caplog.text
    period = 0.1  # the factory's step period (s)
    durations = sorted((n - 1 + h) * period for n, h in zip(lengths, expected))
    assert config["time_base"]["duration_s"] == pytest.approx(durations[1])  # the median, with the held steps
