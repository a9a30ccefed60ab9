"""Input a user can fix is one line and exit 2 naming the option, found before any work where it can be known: seeds
outside what the random generators take, a list option that is no list of numbers, integers too large for any setting, a
training setting `cnep train` refuses given to `cnep sim`, `expert_labels` of the wrong kind in a checkpoint's
config.json, `--pca` past the features' width, and a MuJoCo backend that cannot load (before, each was an internal
error, some after minutes of work)."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cnep.models.checkpoint import CHECKSUM_KEY, CONFIG_FILE, config_checksum
from cnep.models.config import SEED_MAX
from cnep.pipeline.cli.main import main
from cnep.pipeline.errors import PipelineError
from cnep.recordings import write_demonstration, write_trajectory
from tests.recordings.factories import demonstration_factory, trajectory_factory

ROOT = Path(__file__).resolve().parents[2]
HUGE = str(10**23)  # past int64: the parser refuses it
BIG = str(2**40)  # an integer option takes it; a seed is less than 2**32
GIANT = "9" * 4001  # within Python's int-string limit (4300 digits), far past any setting's
SIM = importlib.util.find_spec("mujoco") is not None and importlib.util.find_spec("gymnasium") is not None


@pytest.fixture
def inputs(tmp_path) -> Path:
    write_demonstration(tmp_path / "demo.mcap", demonstration_factory(6, frame_size=16))
    for k in range(3):
        write_trajectory(tmp_path / f"t{k}.mcap", trajectory_factory(12, features=False, seed=k))
    (tmp_path / "policy").mkdir()
    return tmp_path


def one_line(argv: list[str], capsys) -> str:
    """The one error line of `cnep argv`, which must end with exit 2."""
    capsys.readouterr()
    code = main(["-q", *argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, (code, err)
    return err[0]


TRAIN = ["train", "t0.mcap", "t1.mcap", "t2.mcap", "--layout", "motion", "--out", "out"]
SEED_CASES = {  # name -> (arguments, the option named); every one needs no work to be refused
    "demo --seed -1": (["demo", "--quick", "--out", "out", "--seed", "-1"], "--seed"),
    "extract --seed 1e23": (["extract", "demo.mcap", "--out", "out", "--seed", HUGE], "--seed"),
    "train --seed -1": ([*TRAIN, "--seed", "-1"], "--seed"),
    "train --seed 2**40": ([*TRAIN, "--seed", BIG], "--seed"),
    "sim obstacle --seed -1": (["sim", "obstacle", "--out", "out", "--seed", "-1"], "--seed"),
    "sim obstacle --seed 2**40": (["sim", "obstacle", "--out", "out", "--seed", BIG], "--seed"),
    "sim obstacle --train-seeds": (["sim", "obstacle", "--out", "out", "--train-seeds", "0,-1"], "--train-seeds"),
    "sim obstacle --episode-seed": (["sim", "obstacle", "--out", "out", "--episode-seed", "-1"], "--episode-seed"),
    "sim pick-place --seed": (["sim", "pick-place", "--out", "out", "--seed", "-1"], "--seed"),
    "sim pick-place --train-seeds": (["sim", "pick-place", "--out", "out", "--train-seeds", BIG], "--train-seeds"),
    "sim pick-place --episode-seed": (["sim", "pick-place", "--out", "out", "--episode-seed", "-1"], "--episode-seed"),
    "sim eval --episode-seed": (["sim", "eval", "policy", "--episode-seed", "-1"], "--episode-seed"),
    "sim grid --sets": (["sim", "grid", "--out", "out", "--sets", "0,-1"], "--sets"),
    "sim obstacle --train-seeds twice": (["sim", "obstacle", "--out", "out", "--train-seeds", "0,0"], "--train-seeds"),
    "sim grid --train-seeds": (["sim", "grid", "--out", "out", "--train-seeds", BIG], "--train-seeds"),
}


@pytest.mark.parametrize("case", SEED_CASES)
def test_a_seed_outside_what_the_generators_take_is_one_line_before_any_work(inputs, capsys, monkeypatch, case):
    argv, option = SEED_CASES[case]
    if argv[0] == "sim" and not SIM:
        pytest.skip("the sim extra is not installed")
    monkeypatch.chdir(inputs)
    line = one_line(argv, capsys)
    says = "takes distinct values" if case.endswith("twice") else f"must be a whole number from 0 to {SEED_MAX}"
    assert f"{option} {says}" in line, line
    assert "internal error" not in line and not (inputs / "out").exists()


@pytest.mark.parametrize("argv", [[*TRAIN, "--seed", HUGE], ["sim", "obstacle", "--out", "out", "--seed", HUGE]])
def test_a_seed_past_any_integer_setting_is_refused_by_the_parser(inputs, capsys, monkeypatch, argv):
    if argv[0] == "sim" and not SIM:
        pytest.skip("the sim extra is not installed")
    monkeypatch.chdir(inputs)
    capsys.readouterr()
    with pytest.raises(SystemExit) as raised:
        main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        raised.value.code == 2
        and f"argument --seed: expected an integer from -{2**63 - 1} to {2**63 - 1}, got {HUGE}" in err[-1]
    )
    assert not (inputs / "out").exists()


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_episode_seeds_past_the_largest_are_one_line(tmp_path, capsys):
    argv = ["sim", "obstacle", "--out", str(tmp_path / "out"), "--episode-seed", str(SEED_MAX), "--episodes", "2"]
    line = one_line(argv, capsys)
    assert f"--episode-seed {SEED_MAX} and --episodes 2 give episode seeds up to {SEED_MAX + 1}" in line, line


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_a_list_of_seeds_that_is_no_list_of_numbers_says_so(tmp_path, capsys):
    capsys.readouterr()
    with pytest.raises(SystemExit) as raised:
        main(["sim", "obstacle", "--out", str(tmp_path / "out"), "--train-seeds", "a,b"])
    err = capsys.readouterr().err.strip().splitlines()
    assert raised.value.code == 2 and "argument --train-seeds: expected comma-separated whole numbers" in err[-1]
    assert "layer widths" not in err[-1]


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
@pytest.mark.parametrize(
    "task, option, value, message",
    [
        (
            "obstacle",
            "--nll-beta",
            "nan",
            "nll_beta must be in [0, 1] (0: plain NLL; 0.5: the usual beta-NLL), got nan",
        ),
        ("pick-place", "--nll-beta", "2", "nll_beta must be in [0, 1] (0: plain NLL; 0.5: the usual beta-NLL), got 2"),
        ("obstacle", "--feature-components", "-1", "feature_components must be a whole number >= 0"),
    ],
)
def test_a_training_setting_cnep_train_refuses_is_refused_by_cnep_sim_before_any_work(
    inputs, capsys, monkeypatch, task, option, value, message
):
    import cnep.pipeline.sim.stage as sim_stage

    def no_work(*args, **kwargs):
        raise AssertionError("the stages began")

    monkeypatch.setattr(sim_stage, "_run_stages", no_work)
    monkeypatch.chdir(inputs)
    line = one_line(["sim", task, "--out", "out", option, value], capsys)
    assert message in line, line
    assert not (inputs / "out").exists()


def test_a_beta_nll_cnep_train_refuses_is_refused_by_cnep_demo_and_the_baxter_example_before_any_work(
    inputs, capsys, monkeypatch
):
    from cnep.models.errors import ConfigError
    from cnep.pipeline.evaluate.baxter import BaxterConfig

    monkeypatch.chdir(inputs)
    line = one_line(["demo", "--out", "out", "--nll-beta", "2"], capsys)
    assert "nll_beta must be in [0, 1] (0: plain NLL; 0.5: the usual beta-NLL), got 2" in line, line
    assert not (inputs / "out").exists()
    with pytest.raises(ConfigError, match=r"nll_beta must be in \[0, 1\]"):
        BaxterConfig(data=inputs, nll_beta=-1.0)


@pytest.mark.parametrize("setting", ["steps", "seed", "batch_size", "lr"])
def test_a_giant_integer_in_train_config_is_one_short_line_naming_the_setting(inputs, capsys, monkeypatch, setting):
    monkeypatch.chdir(inputs)
    (inputs / "settings.json").write_text(f'{{"{setting}": {GIANT}}}')
    line = one_line([*TRAIN, "--config", "settings.json"], capsys)
    assert f"settings.json: setting {setting} must be" in line and len(line) < 300, line


def test_a_giant_integer_option_is_refused_by_the_parser(inputs, capsys, monkeypatch):
    monkeypatch.chdir(inputs)
    capsys.readouterr()
    with pytest.raises(SystemExit) as raised:
        main([*TRAIN, "--steps", GIANT])
    err = capsys.readouterr().err.strip().splitlines()
    assert raised.value.code == 2 and "argument --steps: " in err[-1] and len(err[-1]) < 300, err[-1][:300]


@pytest.fixture
def edited_checkpoint(motion_world, tmp_path):
    """Write `labels` as the expert_labels of a copy of the motion world's checkpoint (its checksum made to match, as
    an editor who knows it would); returns the copy."""

    def edit(labels: object) -> Path:
        import shutil

        folder = shutil.copytree(motion_world.ckpt, tmp_path / "ckpt")
        config = json.loads((folder / CONFIG_FILE).read_text())
        config.pop(CHECKSUM_KEY)
        config["expert_labels"] = labels
        config[CHECKSUM_KEY] = config_checksum(config)
        (folder / CONFIG_FILE).write_text(json.dumps(config))
        return folder

    return edit


@pytest.mark.parametrize("labels", [[1, 2], "left", {"a": "x"}, {"0": 5}, {"7": "far"}], ids=str)
@pytest.mark.parametrize("command", ["replay", "export"])
def test_expert_labels_of_the_wrong_kind_are_one_line_naming_them(
    motion_world, edited_checkpoint, tmp_path, capsys, one_thread, labels, command
):
    folder = edited_checkpoint(labels)
    argv = {
        "replay": ["replay", str(folder), str(motion_world.trajs / "demo_0.mcap"), "--out", str(tmp_path / "r.rrd")],
        "export": ["export", str(folder), "--out", str(tmp_path / "policy")],
    }[command]
    line = one_line([*argv, *(["--no-live"] if command == "replay" else [])], capsys)
    assert f"{folder / CONFIG_FILE}: expert_labels" in line and "internal error" not in line, line


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_pca_past_the_features_width_is_one_line_before_any_work(tmp_path, capsys):
    line = one_line(["sim", "pick-place", "--out", str(tmp_path / "out"), "--pca", "100000"], capsys)
    assert "--pca must be from 1 to 1280 (the features' width), got 100000" in line, line
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
def test_pca_past_the_training_frames_is_one_line():
    from cnep.pipeline.sim.baselines import check_components

    check_components(3, frames=3, features=1280)
    with pytest.raises(PipelineError, match="--pca 5: the training frames' features have 3 principal components"):
        check_components(5, frames=3, features=1280)


@pytest.mark.skipif(not SIM, reason="the sim extra is not installed")
@pytest.mark.parametrize("backend", ["bogus", "osmesa"])
def test_a_mujoco_backend_that_cannot_load_is_one_line_naming_it(tmp_path, backend):
    if backend == "osmesa":
        import ctypes.util

        if ctypes.util.find_library("OSMesa"):
            pytest.skip("OSMesa is installed here")
    env = {**os.environ, "MUJOCO_GL": backend, "HOME": str(tmp_path), "CI": "1"}
    env.pop("PYOPENGL_PLATFORM", None)  # as in a user's shell (MuJoCo sets it in this process when it loads)
    argv = [sys.executable, "-m", "cnep.pipeline", "sim", "obstacle", "--out", str(tmp_path / "run")]
    done = subprocess.run(argv, capture_output=True, text=True, env=env, cwd=ROOT, timeout=120)
    err = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(err) == 1 and f"MUJOCO_GL={backend}" in err[0], done.stderr
    assert ("libosmesa6" if backend == "osmesa" else "set MUJOCO_GL to egl or osmesa") in err[0], err
    assert not (tmp_path / "run").exists()  # refused before any work
