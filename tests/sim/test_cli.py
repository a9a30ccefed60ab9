"""`cnep sim`: its arguments become the stage's settings, a policy runs on the task it was trained on, `--help` loads
no simulator, and a missing extra is one clear line before any work."""

import builtins
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from cnep.pipeline.cli.main import build_parser, main
from cnep.pipeline.cli.sim import config_of
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.sim.config import (
    ENV_VERSIONS,
    PROTOCOLS,
    SIM_TASKS,
    TASKS,
    EvalConfig,
    PickPlaceConfig,
    SimConfig,
    demonstrations_task,
    task_and_version,
    with_task,
)
from cnep.pipeline.sim.extras import require_extras
from cnep.pipeline.sim.loop import for_task
from cnep.sim.tasks import TASK_NAMES


@pytest.fixture
def find_task():
    """sim.tasks.find_task, where the `sim` extra is installed (a task's folder imports MuJoCo)."""
    import cnep.sim

    if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
        pytest.skip("the sim extra is not installed")
    from cnep.sim.tasks import find_task

    return find_task


def test_obstacle_arguments_become_its_settings_and_the_others_keep_their_defaults():
    args = build_parser().parse_args(["sim", "obstacle", "--out", "x", "--train-seeds", "0,1,2", "--cue"])
    config = config_of(SimConfig, args, out=args.out)
    assert config.train_seeds == (0, 1, 2) and config.cue and config.out == Path("x")
    assert config.episodes == SimConfig.episodes and config.train_steps == SimConfig.train_steps
    assert config.protocols == PROTOCOLS


def test_pick_place_arguments_become_its_settings_and_bad_ones_are_refused(tmp_path, capsys):
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
    assert (config.conditioning.window, config.conditioning.anchors) == (6, 1)
    assert main(["sim", "pick-place", "--out", str(tmp_path / "p"), "--window", "0", "--offline"]) == 2
    err = capsys.readouterr().err.strip()
    assert "window must be >= 1" in err and len(err.splitlines()) == 1 and not (tmp_path / "p").exists()
    with pytest.raises(PipelineError, match="protocol must be one of both, planned, online"):
        PickPlaceConfig(out=Path("x"), protocol="replanned")


@pytest.mark.parametrize("cls", [SimConfig, PickPlaceConfig])
@pytest.mark.parametrize("bad", [{"demonstrations": 1}, {"train_steps": 0}, {"experts": 1}, {"train_seeds": ()}])
def test_both_tasks_refuse_too_little_to_train_in_one_line(cls, bad):
    with pytest.raises(PipelineError, match="need >= 2 demonstrations, >= 1 training step, >= 2 experts and a train"):
        cls(out=Path("x"), **bad)


def test_eval_arguments_become_its_settings():
    args = build_parser().parse_args(["sim", "eval", "policy", "--protocol", "online", "--episodes", "3"])
    config = config_of(EvalConfig, args, policy=args.policy)
    assert (config.policy, config.protocols, config.episodes) == (Path("policy"), ("online",), 3)
    args = build_parser().parse_args(["sim", "eval", "p"])
    assert config_of(EvalConfig, args, policy=args.policy).episodes == EvalConfig.episodes == 50


def test_max_steps_defaults_to_each_tasks_episode_and_must_be_at_least_one(find_task):
    for command, cls, given, task in (
        (["obstacle", "--out", "x"], SimConfig, {"out": "x"}, "obstacle"),
        (["pick-place", "--out", "x"], PickPlaceConfig, {"out": "x"}, "pick-place"),
        (["eval", "p", "--task", "pick-place"], EvalConfig, {"policy": "p"}, "pick-place"),
    ):
        config = config_of(cls, build_parser().parse_args(["sim", *command]), **given)
        on = find_task(task, ENV_VERSIONS[-1])
        assert config.max_steps is None and for_task(config, on).max_steps == on.max_steps
        args = build_parser().parse_args(["sim", *command, "--max-steps", "12"])
        assert for_task(config_of(cls, args, **given), on).max_steps == 12
        with pytest.raises(PipelineError, match="max_steps (and pca )?must be >= 1"):
            cls(**given, max_steps=0)
    assert [(find_task("obstacle", v).max_steps, find_task("pick-place", v).max_steps) for v in ENV_VERSIONS] == [
        (60, 90),  # v0: 6 s, 9 s
        (80, 120),  # v1: 8 s, 12 s (an arm's limits)
    ]


def test_the_environments_version_is_the_latest_unless_given_and_an_unknown_one_is_refused(capsys, find_task):
    for command, cls, given in (
        (["obstacle", "--out", "x"], SimConfig, {"out": "x"}),
        (["pick-place", "--out", "x"], PickPlaceConfig, {"out": "x"}),
    ):
        assert config_of(cls, build_parser().parse_args(["sim", *command]), **given).env_version == ENV_VERSIONS[-1]
        args = build_parser().parse_args(["sim", *command, "--env-version", "0"])
        assert config_of(cls, args, **given).env_version == 0
        with pytest.raises(PipelineError, match="env_version must be one of 0, 1 .*, got 2"):
            cls(**given, env_version=2)
    assert [find_task("pick-place", v).version for v in ENV_VERSIONS] == list(ENV_VERSIONS)
    with pytest.raises(SystemExit) as exited:
        main(["sim", "obstacle", "--out", "x", "--env-version", "2"])
    assert exited.value.code == 2 and "--env-version: invalid choice: 2" in capsys.readouterr().err


def test_a_task_is_a_folder_and_the_commands_know_every_one_without_importing_the_simulator(find_task):
    assert TASKS == TASK_NAMES == ("obstacle", "pick-can", "pick-cube", "pick-place")
    assert all(find_task(name, ENV_VERSIONS[-1]).name == name for name in TASKS)
    assert all(find_task(name, 0).name == name for name in SIM_TASKS)  # the first version: the commands' own tasks
    assert (SimConfig.TASK, PickPlaceConfig.TASK) == SIM_TASKS  # `cnep sim eval` takes every task
    code = (
        "import sys\nfrom cnep.pipeline.cli.main import main\n"
        "for argv in (['--help'], ['sim', '--help'], ['sim', 'pick-place', '--help'], ['sim', 'grid', '--help'],\n"
        "             ['sim', 'eval', '--help']):\n"
        "    try:\n        main(argv)\n    except SystemExit:\n        pass\n"
        "print('loaded:', ','.join(m for m in ('gymnasium', 'mujoco', 'cnep.sim', 'torch') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert done.stdout.splitlines()[-1] == "loaded: "  # a fresh interpreter: --help loads none of them


def _policy_folder(path: Path, task: str, kind: str = "exported") -> Path:
    """A policy folder as `with_task` reads it: a manifest whose spec names `task`, or a checkpoint's config.json
    naming it ("" for none)."""
    path.mkdir()
    tasks = [task] if task else []
    if kind == "exported":
        (path / "manifest.json").write_text(json.dumps({"spec": {"tasks": tasks}}))
    else:
        (path / "config.json").write_text(json.dumps({"tasks": tasks}))
    return path


def test_eval_runs_a_policy_on_the_task_it_was_trained_on_and_refuses_another(tmp_path, capsys, find_task):
    pick = _policy_folder(tmp_path / "pick", "pick-place")
    assert with_task(EvalConfig(policy=pick)).task == "pick-place"
    assert with_task(EvalConfig(policy=pick, task="pick-place")).task == "pick-place"
    assert with_task(EvalConfig(policy=_policy_folder(tmp_path / "ckpt", "obstacle", "checkpoint"))).task == "obstacle"
    assert main(["sim", "eval", str(pick), "--task", "obstacle"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "trained on the pick-place task, --task obstacle runs it in another scene" in err[0], err
    own = _policy_folder(tmp_path / "own", "pick up the cup")  # a user's task: the scene is the user's choice
    with pytest.raises(PipelineError, match="names the task 'pick up the cup', not one of the simulator's; choose"):
        with_task(EvalConfig(policy=own))
    assert with_task(EvalConfig(policy=own, task="obstacle")).task == "obstacle"
    with pytest.raises(
        PipelineError, match="the policy names no task; choose its scene with --task obstacle|pick-place"
    ):
        with_task(EvalConfig(policy=_policy_folder(tmp_path / "old", "")))
    with pytest.raises(PipelineError, match="--cue is a variant of another task; the pick-place task has none"):
        for_task(EvalConfig(policy=pick, task="pick-place", cue=True), find_task("pick-place", 1))


@pytest.mark.parametrize("kind, name", [("exported", "manifest.json"), ("checkpoint", "config.json")])
@pytest.mark.parametrize(
    "text, says",
    [
        ("{oops", "cannot read the (checkpoint's config|policy's manifest)"),
        ("[" * 100_000 + "]" * 100_000, "cannot read the .* \\(nested 100000 levels deep"),
        ("[1, 2]", "the .* holds one JSON object, got list"),
        (json.dumps({"tasks": 5, "spec": {"tasks": 5}}), "its tasks are not a list of task names"),
        (json.dumps({"tasks": [1], "spec": {"tasks": [1]}}), "its tasks are not a list of task names"),
    ],
    ids=["not JSON", "too deep", "a list", "tasks a number", "tasks of numbers"],
)
def test_eval_names_a_policy_file_it_cannot_read_the_task_of_in_one_line(tmp_path, capsys, kind, name, text, says):
    folder = _policy_folder(tmp_path / "policy", "obstacle", kind)
    (folder / name).write_text(text)
    with pytest.raises(PipelineError, match=f"^{folder / name}: {says}"):
        with_task(EvalConfig(policy=folder))
    capsys.readouterr()
    assert main(["-q", "sim", "eval", str(folder)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{folder / name}: " in err[0] and "internal error" not in err[0], err


def test_eval_runs_a_policy_on_the_environments_version_it_was_trained_on_unless_given(tmp_path):
    for version in ENV_VERSIONS:
        label = demonstrations_task("pick-place", version)  # the task `cnep sim` names its demonstrations with
        assert task_and_version(label) == ("pick-place", version)
        policy = _policy_folder(tmp_path / label, label)
        assert (with_task(EvalConfig(policy=policy)).task, with_task(EvalConfig(policy=policy)).env_version) == (
            "pick-place",
            version,
        )
        assert with_task(EvalConfig(policy=policy, env_version=1 - version)).env_version == 1 - version
    assert demonstrations_task("obstacle", 0) == "obstacle" and demonstrations_task("obstacle", 1) == "obstacle-v1"
    assert task_and_version("obstacle-v7") == task_and_version("stack-v1") == ("", None)
    own = _policy_folder(tmp_path / "own", "pick up the cup")  # a user's task runs on the latest version
    assert with_task(EvalConfig(policy=own, task="obstacle")).env_version == ENV_VERSIONS[-1]


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


def test_a_run_checks_every_extra_it_will_need_before_any_work(monkeypatch, capsys, tmp_path):
    real_find_spec = importlib.util.find_spec
    hidden = {"gmr", "onnxruntime"}
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name in hidden else real_find_spec(name, *a)
    )
    assert main(["sim", "pick-place", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs the onnx and baselines extras (onnxruntime, gmr not installed)" in err[0], err
    assert "pip install 'cnep-pipeline[onnx,baselines]', or leave the baselines out: --no-baselines" in err[0]
    assert not (tmp_path / "o").exists()
    hidden.discard("onnxruntime")
    require_extras(PickPlaceConfig(out=tmp_path / "o", baselines=False), "cnep sim pick-place")  # none missing
    require_extras(SimConfig(out=tmp_path / "o"), "cnep sim obstacle")  # the obstacle runs no baselines by default
    hidden.add("onnxruntime")
    exported = _policy_folder(tmp_path / "exported", "obstacle")
    with pytest.raises(PipelineError, match=r"cnep sim eval needs the onnx extra \(onnxruntime not installed\)"):
        require_extras(EvalConfig(policy=exported), "cnep sim eval")
    require_extras(EvalConfig(policy=_policy_folder(tmp_path / "ckpt", "obstacle", "checkpoint")), "cnep sim eval")
