"""`cnep sim`: its arguments become the stage's settings, and a missing `sim` extra is one clear line."""

import builtins
import importlib.util
from pathlib import Path

import pytest

from cnep.pipeline.cli.main import build_parser, main
from cnep.pipeline.cli.sim import config_of
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.sim.config import PROTOCOLS, EvalConfig, PickPlaceConfig, SimConfig
from cnep.sim.tasks.obstacle import scene as O
from cnep.sim.tasks.pick_place import scene as P


def test_obstacle_arguments_become_its_settings_and_the_others_keep_their_defaults():
    args = build_parser().parse_args(["sim", "obstacle", "--out", "x", "--train-seeds", "0,1,2", "--cue"])
    config = config_of(SimConfig, args, out=args.out)
    assert config.train_seeds == (0, 1, 2) and config.cue and config.out == Path("x")
    assert config.episodes == SimConfig.episodes and config.train_steps == SimConfig.train_steps
    assert config.protocols == PROTOCOLS


def test_pick_place_arguments_become_its_settings_and_bad_ones_are_refused():
    args = build_parser().parse_args(["sim", "pick-place", "--out", "x", "--episodes", "3", "--no-baselines"])
    config = config_of(PickPlaceConfig, args, out=args.out)
    assert (config.episodes, config.baselines, config.out) == (3, False, Path("x"))
    assert config.experts == PickPlaceConfig.experts and config.pca == PickPlaceConfig.pca
    assert config.protocols == PROTOCOLS
    args = build_parser().parse_args(["sim", "pick-place", "--out", "x", "--protocol", "planned"])
    assert config_of(PickPlaceConfig, args, out=args.out).protocols == ("planned",)
    with pytest.raises(PipelineError, match="pca must be >= 1"):
        PickPlaceConfig(out=Path("x"), pca=0)
    args = build_parser().parse_args(["sim", "pick-place", "--out", "x", "--window", "6", "--anchors", "1"])
    config = config_of(PickPlaceConfig, args, out=args.out)
    assert (config.window, config.anchors) == (6, 1)
    with pytest.raises(PipelineError, match="window must be >= 1 and anchors >= 0, got 0 and 0"):
        PickPlaceConfig(out=Path("x"), window=0)
    with pytest.raises(PipelineError, match="protocol must be one of both, planned, online"):
        PickPlaceConfig(out=Path("x"), protocol="replanned")


def test_eval_arguments_become_its_settings():
    args = build_parser().parse_args(["sim", "eval", "policy", "--protocol", "online", "--episodes", "3"])
    config = config_of(EvalConfig, args, policy=args.policy)
    assert (config.policy, config.protocols, config.episodes) == (Path("policy"), ("online",), 3)
    args = build_parser().parse_args(["sim", "eval", "p"])
    assert config_of(EvalConfig, args, policy=args.policy).episodes == EvalConfig.episodes == 50


def test_max_steps_defaults_to_each_tasks_episode_and_must_be_at_least_one():
    for command, cls, given, task_steps in (
        (["obstacle", "--out", "x"], SimConfig, {"out": "x"}, O.MAX_STEPS),
        (["pick-place", "--out", "x"], PickPlaceConfig, {"out": "x"}, P.MAX_STEPS),
        (["eval", "p"], EvalConfig, {"policy": "p"}, O.MAX_STEPS),
    ):
        assert config_of(cls, build_parser().parse_args(["sim", *command]), **given).max_steps == task_steps
        args = build_parser().parse_args(["sim", *command, "--max-steps", "12"])
        assert config_of(cls, args, **given).max_steps == 12
        with pytest.raises(PipelineError, match="max_steps (and pca )?must be >= 1"):
            cls(**given, max_steps=0)


def test_an_unknown_protocol_is_refused(capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        main(["sim", "eval", str(tmp_path), "--protocol", "offline"])
    assert exit_.value.code == 2
    assert "invalid choice: 'offline'" in capsys.readouterr().err


def test_without_the_sim_extra_the_command_says_how_to_install_it(monkeypatch, capsys, tmp_path):
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "mujoco" else real_find_spec(name, *a)
    )
    real_import = builtins.__import__

    def no_mujoco(name, *args, **kwargs):
        if name == "mujoco":
            raise ModuleNotFoundError("No module named 'mujoco'", name="mujoco")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_mujoco)
    (tmp_path / "policy").mkdir()
    (tmp_path / "policy" / "manifest.json").write_text("{}")
    for command in (["sim", "eval", str(tmp_path / "policy")], ["sim", "pick-place", "--out", str(tmp_path / "o")]):
        assert main(command) != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "pip install 'cnep-pipeline[sim]'" in err[0], err
    assert not (tmp_path / "o").exists()
    with pytest.raises(Exception, match="mujoco"):
        import mujoco  # noqa: F401
