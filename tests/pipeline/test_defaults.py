"""One default per setting: `cnep train`, the train stage's config and the models' configs train the same model."""

import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import pytest

from cnep.models.config import CNEPConfig, ConditioningOverrides, ConditioningPolicy, TrainConfig
from cnep.pipeline.cli.demo import demo_config
from cnep.pipeline.cli.export import conditioning_given
from cnep.pipeline.cli.main import build_parser
from cnep.pipeline.cli.train import settings_of, stage_config
from cnep.pipeline.demo.config import CNEP_EXPERTS, DemoConfig
from cnep.pipeline.extract.stage import ExtractConfig
from cnep.pipeline.ingest.stage import IngestConfig
from cnep.pipeline.train.config import TrainStageConfig


def test_cnep_train_without_flags_is_the_stage_config_with_its_defaults():
    args = build_parser().parse_args(["train", "data", "--out", "ckpt"])
    assert stage_config(args) == TrainStageConfig(inputs=(Path("data"),), out=Path("ckpt"))


def test_the_cli_the_stage_config_and_the_model_configs_agree_on_every_shared_setting():
    stage = TrainStageConfig(inputs=(), out=Path("ckpt"))
    model, training = CNEPConfig(), TrainConfig()
    assert stage.model == model and stage.training == training  # held, not copied
    assert model.assignment == "bounded" and training.patience == 10 and training.threads == 1
    args = build_parser().parse_args(["train", "data", "--out", "ckpt"])
    chosen = stage_config(args)
    held = {
        TrainStageConfig: chosen,
        CNEPConfig: chosen.model,
        TrainConfig: chosen.training,
        ConditioningPolicy: chosen.conditioning,
    }
    for option in settings_of().values():
        owner = next(cls for cls in held if option.field in fields(cls))
        assert getattr(held[owner], option.field.name) == option.field.default, option.name
    demo = demo_config(build_parser().parse_args(["demo", "--out", "d"]))
    assert demo == DemoConfig(out=Path("d")) and demo.model.assignment == model.assignment
    assert demo.model.n_experts == CNEP_EXPERTS and demo.seed == 0
    assert chosen.conditioning == ConditioningPolicy()
    for argv in (["replay", "ckpt", "r.mcap"], ["run", "p", "r.mcap", "--out", "r.rrd"], ["export", "c", "--out", "p"]):
        assert conditioning_given(build_parser().parse_args(argv)) == ConditioningOverrides()  # the policy's own


def test_nested_options_reach_the_config_they_belong_to():
    args = build_parser().parse_args(["train", "d", "--out", "c", "--experts", "3", "--steps", "50", "--force"])
    config = stage_config(args)
    assert (config.model.n_experts, config.training.steps, config.force) == (3, 50, True)
    assert config.model == CNEPConfig(n_experts=3)  # the loss weights follow the number of experts
    demo = demo_config(build_parser().parse_args(["demo", "--out", "d", "--assignment", "paper", "--experts", "6"]))
    assert demo.model == CNEPConfig(n_experts=6, assignment="paper") and not demo.quick


def option_help(text: str, flag: str) -> str:
    """The help of `flag` in argparse's --help output, on one line."""
    block, found = [], False
    for line in text.splitlines():
        if line.startswith("  -"):
            found = line.split()[0] == flag
        elif not line.startswith("   "):
            found = False
        if found:
            block.append(line)
    return " ".join(" ".join(block).split())


@pytest.mark.parametrize("option", sorted(name for name, o in settings_of().items() if not o.is_flag))
def test_cnep_train_help_shows_each_dataclass_default(option, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "10000")  # one line per option: argparse wraps a long one at its hyphens
    with pytest.raises(SystemExit):
        build_parser().parse_args(["train", "--help"])
    shown = option_help(capsys.readouterr().out, f"--{option.replace('_', '-')}")
    field = settings_of()[option].field
    default = field.default
    expected = (
        field.metadata.get("shown", "the assignment's")
        if default is None
        else ",".join(map(str, default))
        if isinstance(default, tuple)
        else default
    )
    assert f"(default {expected}" in shown, shown


def test_the_python_defaults_train_the_committing_model_in_a_fresh_interpreter():
    code = "from cnep.models import CNEPConfig; print(CNEPConfig().assignment)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "bounded"


def test_cnep_run_takes_its_defaults_from_run_config():
    from cnep.pipeline.run import RunConfig

    args = build_parser().parse_args(["run", "policy", "r.mcap", "--out", "r.rrd"])
    config = RunConfig(Path("policy"), (Path("r.mcap"),), out=Path("r.rrd"))
    names = ("precision", "backend", "threads", "waypoints", "time_base")
    assert {n: getattr(args, n) for n in names} == {n: getattr(config, n) for n in names}


@pytest.mark.parametrize(
    "make",
    [
        lambda: TrainStageConfig(inputs=("trajectories", Path("more")), out="model"),
        lambda: ExtractConfig(inputs="demos", out="trajectories", calibrate_on=["demos/train"]),
        lambda: IngestConfig(src="raw", out="demos"),
        lambda: DemoConfig(out="cnep-demo"),
    ],
)
def test_a_stage_config_made_from_python_with_strings_holds_paths(make):
    """What the `cnep` command passes as Paths, Python code may pass as strings (a lone string for a tuple of paths
    is one path): the stages then see the same config."""
    config = make()
    checked = 0
    for f in fields(config):
        value = getattr(config, f.name)
        if f.type in ("Path", "Path | None"):
            assert value is None or isinstance(value, Path), f.name
            checked += 1
        if f.type == "tuple[Path, ...]":
            assert isinstance(value, tuple) and all(isinstance(v, Path) for v in value), f.name
            assert value == tuple(Path(v) for v in value) and value, f.name
            checked += 1
    assert checked >= 1
