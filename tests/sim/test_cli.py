"""`cnep sim`: its arguments become the stage's settings, and a missing `sim` extra is one clear line."""

import builtins
import importlib.util

import pytest

from cnep.pipeline.cli.main import build_parser, main
from cnep.pipeline.sim.config import PROTOCOLS, EvalConfig, SimConfig


def test_obstacle_arguments_and_their_defaults():
    args = build_parser().parse_args(["sim", "obstacle", "--out", "x", "--train-seeds", "0,1,2", "--cue"])
    assert args.train_seeds == (0, 1, 2) and args.cue and args.out == "x"
    assert args.episodes == SimConfig.episodes and args.train_steps == SimConfig.train_steps
    assert args.protocols == PROTOCOLS


def test_eval_arguments_and_their_defaults():
    args = build_parser().parse_args(["sim", "eval", "policy", "--protocols", "online", "--episodes", "3"])
    assert (args.policy, args.protocols, args.episodes) == ("policy", ("online",), 3)
    assert build_parser().parse_args(["sim", "eval", "p"]).episodes == EvalConfig.episodes


def test_an_unknown_protocol_is_one_line(capsys, tmp_path):
    assert main(["sim", "eval", str(tmp_path), "--protocols", "offline"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "protocols must be among planned, online" in err[0]


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
    assert main(["sim", "eval", str(tmp_path / "policy")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'cnep-pipeline[sim]'" in err[0], err
    with pytest.raises(Exception, match="mujoco"):
        import mujoco  # noqa: F401
