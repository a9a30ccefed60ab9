"""A setting is one dataclass field: added in a subclass, it reaches `--help`, the CLI reference and config.json."""

from dataclasses import dataclass, field

import pytest

from cnep.models import read_checkpoint_config
from cnep.models.config import CNEPConfig, TrainConfig, setting
from cnep.pipeline.cli import train as train_command
from cnep.pipeline.cli.main import build_parser, main
from cnep.pipeline.cli.reference import render
from cnep.pipeline.train.config import TrainStageConfig
from tests.pipeline.test_train import write_set

pytestmark = pytest.mark.usefixtures("one_thread")


@dataclass(frozen=True)
class KnobTraining(TrainConfig):
    knob: float = setting(0.25, "a training setting that only this test has")


@dataclass(frozen=True)
class KnobModel(CNEPConfig):
    dial: int = setting(7, "a model setting that only this test has")


@dataclass(frozen=True)
class KnobStage(TrainStageConfig):
    model: KnobModel = field(default_factory=KnobModel)
    training: KnobTraining = field(default_factory=KnobTraining)


@pytest.fixture
def knob_stage(monkeypatch):
    monkeypatch.setattr(train_command, "STAGE", KnobStage)


def test_a_new_field_is_an_option_with_its_help_and_default_in_help_and_the_reference(knob_stage, capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "--knob KNOB a training setting that only this test has (default 0.25)" in shown
    assert "--dial DIAL a model setting that only this test has (default 7)" in shown
    page = render()
    assert "| `--knob KNOB` | a training setting that only this test has (default 0.25) |" in page
    assert "| `--dial DIAL` | a model setting that only this test has (default 7) |" in page


def test_a_new_field_reaches_the_stage_and_the_checkpoints_config_json(knob_stage, tmp_path, capsys):
    data = write_set(tmp_path / "data")
    out = tmp_path / "ckpt"
    tiny = ["--steps", "4", "--val-every", "2", "--warmup-steps", "1", "--batch-size", "4"]
    widths = ["--encoder-widths", "8", "--expert-widths", "8", "--layout", "motion"]
    code = main(["-q", "train", str(data[0].parent), "--out", str(out), *tiny, *widths, "--knob", "0.5", "--dial", "3"])
    assert code == 0, capsys.readouterr().err
    config = read_checkpoint_config(out)
    assert config["training"]["knob"] == 0.5 and config["model"]["dial"] == 3
    args = build_parser().parse_args(["train", "d", "--out", "c"])
    assert train_command.stage_config(args).training == KnobTraining()  # not given: the field's default
