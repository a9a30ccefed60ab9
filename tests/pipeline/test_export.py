"""`cnep export`: the graphs, the manifest and the runtime's source, each checked, and what is refused."""

import json
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cnep.models import load_checkpoint, read_checkpoint_config
from cnep.models.checkpoint import CHECKSUM_KEY, CONFIG_FILE, config_checksum
from cnep.models.online import TorchNetwork
from cnep.pipeline.cli.main import main
from cnep.pipeline.export.policy import checkpoint_policy
from cnep.pipeline.run.stage import observations
from cnep.recordings import read_demonstration, read_trajectory
from cnep.recordings.constants import BLOCK_GRIPPER
from cnep.runtime import (
    STATE_KEY,
    ConditioningPolicy,
    GripperCommand,
    PolicyError,
    TimeBase,
    load_policy,
    read_manifest,
)
from cnep.runtime.constants import RUNTIME_REQUIREMENTS
from cnep.runtime.exported import ENCODER_INPUT
from cnep.runtime.frames import decode_frame
from cnep.runtime.manifest import file_sha256
from cnep.runtime.sessions import installed_backends, onnxruntime_graph
from tests.outputs.test_outputs import dead_pid

ROOT = Path(__file__).resolve().parents[2]


def test_the_folder_holds_what_the_manifest_lists_with_the_checkpoints_spec(policy_world):
    folder = policy_world.exported
    manifest = read_manifest(folder)
    on_disk = {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()} - {"manifest.json"}
    assert set(manifest.files) == on_disk
    assert all(file_sha256(folder / name) == sha for name, sha in manifest.files.items())
    config = read_checkpoint_config(policy_world.checkpoint)
    assert manifest.spec.time_base.to_dict() == config["time_base"]
    assert manifest.spec.time_base.duration_s > manifest.spec.time_base.period_s > 0
    assert manifest.extractor == config["extractor"]
    assert manifest.features["fp32"]["identity"]["weights_sha256"] == config["extractor"]["weights_sha256"]
    assert manifest.features["int8"]["identity"]["precision"] == "int8"
    assert manifest.spec.action_names == ("x", "y", "z", "qx", "qy", "qz", "qw", "gripper")
    trained = [read_trajectory(f["path"]) for f in config["files"]]  # every file cnep train was given
    values = np.concatenate([t.data[:, slice(*t.blocks[BLOCK_GRIPPER])].ravel() for t in trained])
    starts = [t.data[0, t.blocks[BLOCK_GRIPPER][0]] for t in trained]
    assert (
        manifest.spec.gripper
        == GripperCommand.from_demonstrations(values, starts)
        == GripperCommand.from_dict(config["gripper"])
    )
    assert manifest.spec.gripper.closed == "low"  # the demo's gripper is an opening: its demonstrations start open
    assert manifest.spec.gripper.high - manifest.spec.gripper.low > 0.5 * (values.max() - values.min())
    np.testing.assert_array_equal(
        manifest.spec.columns.loc, load_checkpoint(policy_world.checkpoint).normaliser.loc.numpy()
    )
    for path in (ROOT / "runtime").glob("*.py"):  # the runtime's own source, as installed with this package
        assert (folder / "runtime" / "cnep" / "runtime" / path.name).read_bytes() == path.read_bytes()
    assert all(r in (folder / "runtime" / "pyproject.toml").read_text() for r in RUNTIME_REQUIREMENTS)


def test_the_encoder_graph_takes_any_number_of_context_points(policy_world):
    model = load_checkpoint(policy_world.checkpoint)
    graph = onnxruntime_graph(str(policy_world.exported / "encoder.onnx"), 1)
    rng = np.random.default_rng(0)
    for n in (1, 5, 40):
        obs = rng.standard_normal((n, 1 + model.config.columns.obs_dim), dtype=np.float32)
        np.testing.assert_allclose(graph({ENCODER_INPUT: obs})[0], TorchNetwork(model).encode(obs), atol=1e-5)


def test_an_exported_policy_reading_feature_components_encodes_as_its_checkpoint(policy_world, tmp_path):
    trajectories = policy_world.checkpoint.parents[1] / "trajectories" / "train"
    checkpoint, folder = tmp_path / "ckpt", tmp_path / "policy"
    tiny = ["--steps", "4", "--val-every", "2", "--warmup-steps", "1", "--encoder-widths", "8", "--expert-widths", "8"]
    assert main(["-q", "train", str(trajectories), "--out", str(checkpoint), *tiny, "--feature-components", "3"]) == 0
    assert (
        main(["-q", "export", str(checkpoint), "--out", str(folder), "--extractor", str(policy_world.extractor)]) == 0
    )
    model = load_checkpoint(checkpoint)
    graph = onnxruntime_graph(str(folder / "encoder.onnx"), 1)
    obs = np.random.default_rng(0).standard_normal((5, 1 + model.config.columns.obs_dim), dtype=np.float32)
    encoded = graph({ENCODER_INPUT: obs})[0]
    np.testing.assert_allclose(encoded, TorchNetwork(model).encode(obs), atol=1e-5)
    model.feature_projection.zero_()  # the graph holds the projection: without it, the encodings differ
    assert np.abs(encoded - TorchNetwork(model).encode(obs)).max() > 1e-3


def test_the_runtime_requirements_are_the_packages_bounds():
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = {*project["dependencies"], *project["optional-dependencies"]["onnx"]}
    assert set(RUNTIME_REQUIREMENTS) <= declared


def test_a_changed_file_or_an_unknown_version_is_refused(policy_world, tmp_path):
    folder = tmp_path / "policy"
    shutil.copytree(policy_world.exported, folder)
    decoder = folder / "decoder.onnx"
    decoder.write_bytes(decoder.read_bytes()[:-1] + b"\0")
    with pytest.raises(PolicyError, match="decoder.onnx: sha256 .* changed or damaged"):
        load_policy(folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    (folder / "manifest.json").write_text(json.dumps({**manifest, "format_version": 99}))
    with pytest.raises(PolicyError, match="format_version 99 is not supported"):
        load_policy(folder)
    with pytest.raises(PolicyError, match="this is a checkpoint folder"):
        load_policy(policy_world.checkpoint)
    with pytest.raises(PolicyError, match="no int8 feature graph"):
        export_motion = tmp_path / "motion"
        main(["-q", "export", str(policy_world.checkpoint), "--out", str(export_motion), "--extractor",
              str(policy_world.extractor)])  # fmt: skip
        load_policy(export_motion, precision="int8")


def test_a_folder_that_points_outside_itself_or_holds_an_extra_file_is_refused_by_cnep_run(
    policy_world, tmp_path, capsys
):
    folder = tmp_path / "policy"
    shutil.copytree(policy_world.exported, folder)
    (folder / "runtime" / "build").mkdir()  # what `pip install policy/runtime` leaves is ignored: never read
    (folder / "runtime" / "build" / "stale.py").write_text("")
    assert load_policy(folder).uses_camera
    manifest = json.loads((folder / "manifest.json").read_text())

    def run(*argv):
        capsys.readouterr()
        code = main(["-q", "run", str(folder), str(policy_world.heldout), "--out", str(tmp_path / "r.rrd"), *argv])
        return code, capsys.readouterr().err.strip()

    passwd = Path("/etc/passwd")
    for name in ("../../../../../../etc/passwd", "../outside_encoder.onnx", str(passwd.resolve())):
        shutil.copy(folder / "encoder.onnx", tmp_path / "outside_encoder.onnx")
        source = passwd if "passwd" in name else tmp_path / "outside_encoder.onnx"
        graphs, files = {**manifest["graphs"], "encoder": name}, {**manifest["files"], name: file_sha256(source)}
        (folder / "manifest.json").write_text(json.dumps({**manifest, "graphs": graphs, "files": files}))
        code, err = run()
        assert code == 2 and len(err.splitlines()) == 1 and "not a plain file name inside the folder" in err, err
    (folder / "manifest.json").write_text(json.dumps(manifest))
    (folder / "sitecustomize.py").write_text("import os\n")
    code, err = run()
    assert code == 2 and f"{folder / 'sitecustomize.py'}: a file that manifest.json does not list" in err
    assert not (tmp_path / "r.rrd").exists()


def test_a_format_1_folder_loads_without_a_gripper_command(policy_world, tmp_path):
    folder = tmp_path / "policy"
    shutil.copytree(policy_world.exported, folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["format_version"] == 2 and manifest["spec"]["gripper"] is not None
    del manifest["spec"]["gripper"]
    manifest["spec"]["conditioning"] = {"window": 10, "anchors": 1}  # what format 1 holds
    (folder / "manifest.json").write_text(json.dumps({**manifest, "format_version": 1}))
    policy, demo = load_policy(folder), read_demonstration(policy_world.heldout)
    step = policy.step({"observation.images.front": decode_frame(demo.frames[0]),
                        STATE_KEY: np.r_[demo.pose[0], demo.gripper[0]]})  # fmt: skip
    assert policy.gripper is None and step.gripper is None
    assert policy.spec.conditioning == ConditioningPolicy()


def test_a_motion_model_exports_without_a_feature_graph_and_runs_on_the_state_alone(policy_world, tmp_path):
    assert main(["-q", "export", str(policy_world.motion_checkpoint), "--out", str(tmp_path / "p")]) == 0
    assert not (tmp_path / "p" / "features.onnx").exists()
    policy = load_policy(tmp_path / "p", waypoints=3)
    demo = read_demonstration(policy_world.heldout)
    state = np.concatenate([demo.pose, demo.gripper[:, None]], axis=1)
    steps = [policy.step({STATE_KEY: row}) for row in state]
    assert steps[-1].waypoints.shape == (3, 8) and not policy.uses_camera


def test_export_refuses_what_it_cannot_do(policy_world, tmp_path, capsys):
    def cnep(*argv):
        capsys.readouterr()
        code = main(["-q", "export", *map(str, argv)])
        return code, capsys.readouterr().err.strip()

    code, err = cnep(policy_world.checkpoint, "--out", tmp_path / "p")
    assert code == 2 and "--extractor" in err and "extractor.pt" in err and not (tmp_path / "p").exists()
    code, err = cnep(policy_world.checkpoint, "--out", tmp_path / "p", "--extractor", policy_world.heldout)
    assert code == 2 and str(policy_world.heldout) in err
    code, err = cnep(policy_world.checkpoint, "--out", tmp_path / "p", "--extractor", policy_world.extractor, "--int8")
    assert code == 2 and "--calibration" in err
    (tmp_path / "p").mkdir()
    code, err = cnep(policy_world.checkpoint, "--out", tmp_path / "p", "--extractor", policy_world.extractor)
    assert code == 2 and "--force" in err and list((tmp_path / "p").iterdir()) == []
    code, err = cnep(tmp_path / "nope", "--out", tmp_path / "q")
    assert code == 2 and str(tmp_path / "nope") in err


def test_the_export_replaces_a_folder_only_with_force(policy_world, tmp_path):
    out = tmp_path / "p"
    argv = ["-q", "export", str(policy_world.motion_checkpoint), "--out", str(out)]
    assert main(argv) == 0
    before = read_manifest(out).files
    assert main([*argv, "--force"]) == 0
    assert read_manifest(out).files == before  # the same checkpoint exports to the same bytes
    assert [p.name for p in tmp_path.iterdir()] == ["p"]  # no work folder left beside it
    (out / "notes.txt").write_text("mine")
    assert main([*argv, "--force"]) == 2  # --force replaces what cnep export wrote, never a user's own file
    assert (out / "notes.txt").read_text() == "mine" and read_manifest(out).files == before


def test_an_export_stopped_while_replacing_a_folder_leaves_it_restored(policy_world, tmp_path):
    out = tmp_path / "p"
    argv = ["-q", "export", str(policy_world.motion_checkpoint), "--out", str(out)]
    assert main(argv) == 0
    before = read_manifest(out).files
    aside = tmp_path / f".p.replaced-{dead_pid()}-abcdef"  # where a killed run set the old folder aside
    out.rename(aside)  # killed between moving the old folder aside and renaming the new one in
    assert main(argv) == 2  # the old folder is back in place, so without --force it is refused
    assert read_manifest(out).files == before and [p.name for p in tmp_path.iterdir()] == ["p"]
    out.rename(aside)
    shutil.copytree(aside, out)  # killed after the new folder was renamed in
    assert main([*argv, "--force"]) == 0
    assert read_manifest(out).files == before and [p.name for p in tmp_path.iterdir()] == ["p"]


def test_a_checkpoint_without_a_time_base_exports_with_one_given(policy_world, tmp_path, capsys):
    checkpoint = tmp_path / "ckpt"
    shutil.copytree(policy_world.motion_checkpoint, checkpoint)
    config = json.loads((checkpoint / CONFIG_FILE).read_text())
    del config["time_base"]
    config[CHECKSUM_KEY] = config_checksum(config)
    (checkpoint / CONFIG_FILE).write_text(json.dumps(config))
    out = tmp_path / "p"
    capsys.readouterr()
    assert main(["-q", "export", str(checkpoint), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert str(checkpoint / CONFIG_FILE) in err and "--time-base" in err and not out.exists()
    assert main(["-q", "export", str(checkpoint), "--out", str(out), "--time-base", "3.9,0.1"]) == 0
    assert read_manifest(out).spec.time_base == TimeBase(3.9, 0.1)


def policies(policy_world):
    """The demo's policy exported (ONNX Runtime) and as its checkpoint (torch), with an observation of the held-out
    recording's first step."""
    exported = load_policy(policy_world.exported, threads=1)
    checkpoint = checkpoint_policy(policy_world.checkpoint, policy_world.extractor, backend="eager", threads=1)
    observation = next(observations(read_demonstration(policy_world.heldout), policy_world.heldout))
    return {"exported": exported, "checkpoint": checkpoint}, observation


@pytest.mark.parametrize("reading", [3e38, 1e300, -3e38, 1e6])
def test_a_gripper_reading_far_outside_the_training_is_refused_by_both_policies_never_a_nan(policy_world, reading):
    found, observation = policies(policy_world)
    for kind, policy in found.items():
        state = np.array(observation[STATE_KEY], dtype=np.float64)
        state[-1] = reading  # a sensor's "no reading" value, or another unit
        with pytest.raises(PolicyError, match=f"{STATE_KEY}: gripper = .* lies outside"):
            policy.select_action({**observation, STATE_KEY: state})
        action = policy.select_action(observation)
        assert np.isfinite(action).all(), kind


def damaged(folder: Path, graph: str, how: str) -> None:
    """Damage `graph` of the exported `folder` as `how` says, and list the new bytes in the manifest (so that the
    sha256 check passes and the graph reaches its backend)."""
    onnx = pytest.importorskip("onnx")
    path = folder / graph
    if how == "corrupt":
        data = bytearray(path.read_bytes())
        data[:100] = b"\x07" * 100
        path.write_bytes(bytes(data))
    elif how == "swapped":
        other = folder / ("decoder.onnx" if graph == "encoder.onnx" else "encoder.onnx")
        first, second = path.read_bytes(), other.read_bytes()
        path.write_bytes(second)
        other.write_bytes(first)
    else:  # external data beside the folder, which the graph points to: outside it
        model = onnx.load(str(path))
        onnx.save_model(model, str(path), save_as_external_data=True, location="weights.bin", size_threshold=0)
        shutil.move(folder / "weights.bin", folder.parent / "weights.bin")
        model = onnx.load(str(path), load_external_data=False)
        for tensor in model.graph.initializer:
            for entry in tensor.external_data:
                if entry.key == "location":
                    entry.value = "../weights.bin"
        path.write_bytes(model.SerializeToString())
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["files"] = {name: file_sha256(folder / name) for name in manifest["files"]}
    (folder / "manifest.json").write_text(json.dumps(manifest))


DAMAGES = [
    ("encoder.onnx", "corrupt", "cannot load it"),
    ("features.onnx", "corrupt", "cannot load it"),
    ("encoder.onnx", "swapped", "cannot run it"),
    ("decoder.onnx", "outside", "cannot load it .*(outside|escapes)"),
]


@pytest.mark.parametrize("graph, how, says", DAMAGES)
def test_a_damaged_swapped_or_escaping_graph_is_one_policy_error_naming_it(policy_world, tmp_path, graph, how, says):
    folder = tmp_path / "policy"
    shutil.copytree(policy_world.exported, folder)
    damaged(folder, graph, how)
    with pytest.raises(PolicyError, match=f"^{folder / graph}: onnxruntime {says}.*export the checkpoint again$"):
        load_policy(folder, threads=1)


@pytest.mark.skipif("openvino" not in installed_backends(), reason="needs OpenVINO")
def test_openvino_turns_the_same_damage_into_one_policy_error_naming_the_graph(policy_world, tmp_path):
    """In a process of its own: OpenVINO's threads, left in the test process, crash a later torch test."""
    folders = []
    for k, (graph, how, _) in enumerate(DAMAGES):
        folders.append(tmp_path / f"policy-{k}")
        shutil.copytree(policy_world.exported, folders[-1])
        damaged(folders[-1], graph, how)
    code = f"""
        from cnep.runtime import PolicyError, load_policy
        for folder in {[str(f) for f in folders]!r}:
            try:
                load_policy(folder, backend="openvino", threads=1)
            except PolicyError as exc:
                print(exc)
        """
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120)
    lines = done.stdout.splitlines()
    assert done.returncode == 0 and len(lines) == len(DAMAGES), done.stderr
    for line, folder, (graph, _, says) in zip(lines, folders, DAMAGES):
        assert re.match(f"^{folder / graph}: openvino {says}.*export the checkpoint again$", line), line


def test_a_graph_of_another_model_is_refused_when_loaded(policy_world, tmp_path):
    """The motion model's decoder in the demo's folder: valid ONNX, the names a decoder takes, another model's
    shapes."""
    other = tmp_path / "motion"
    assert main(["-q", "export", str(policy_world.motion_checkpoint), "--out", str(other)]) == 0
    folder = tmp_path / "policy"
    shutil.copytree(policy_world.exported, folder)
    shutil.copy(other / "decoder.onnx", folder / "decoder.onnx")
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["files"]["decoder.onnx"] = file_sha256(folder / "decoder.onnx")
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(PolicyError, match=f"^{folder / 'decoder.onnx'}: (gives a gate of shape|onnxruntime cannot)"):
        load_policy(folder, threads=1)


def test_the_manifest_records_the_tasks_and_the_camera_trained_on_and_a_frame_of_another_size_is_refused(
    policy_world, tmp_path
):
    config = read_checkpoint_config(policy_world.checkpoint)
    demo = read_demonstration(sorted(policy_world.demos.glob("*.mcap"))[0])
    height, width = decode_frame(demo.frames[0]).shape[:2]
    tasks = {read_demonstration(p).episode.task for p in policy_world.demos.glob("*.mcap")}
    assert config["tasks"] == sorted(tasks - {""})
    assert config["image_size"] == [height, width] and config["image_key"] is None  # generated: no camera named
    spec = read_manifest(policy_world.exported).spec
    assert spec.tasks == tuple(config["tasks"]) and spec.image_size == (height, width) and spec.image_key is None
    found, observation = policies(policy_world)
    key = next(k for k in observation if k.startswith("observation.images."))
    half = observation[key][::2, ::2]
    for policy in found.values():
        assert policy.spec.tasks == spec.tasks and policy.spec.image_size == spec.image_size
        with pytest.raises(PolicyError, match=f"a frame of {width // 2}x{height // 2} pixels, but this policy was "
                           f"trained on frames of {width}x{height}"):  # fmt: skip
            policy.step({**observation, key: half})
    assert read_checkpoint_config(policy_world.motion_checkpoint)["image_size"] is None  # sees no camera
    folder = tmp_path / "policy"  # a manifest written before the tasks and the camera were stored: any frame size
    shutil.copytree(policy_world.exported, folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["spec"] = {k: v for k, v in manifest["spec"].items() if k not in ("tasks", "image_key", "image_size")}
    (folder / "manifest.json").write_text(json.dumps(manifest))
    older = load_policy(folder, threads=1)
    assert older.spec.tasks == () and np.isfinite(older.step({**observation, key: half}).waypoints).all()


def test_a_switch_of_the_exported_and_the_checkpoint_policy_continues_from_the_recorded_pose(policy_world, tmp_path):
    """The most switching settings on the set the model trained on (a first expert drawn from the gate, each
    recording with a seed of its own, then the gate's argmax) over the demo's recordings (its scene change and free
    choices among them), then the checkpoint policy over the one that switched most: at every switch the first
    waypoint lies within the largest step of the recorded pose on each axis. The quick demo's few steps are large (its
    largest step is what a switch jumps anyway), so the folder and the checkpoint are given 2 cm."""
    tight = dict.fromkeys(("x", "y", "z"), 0.02)
    folder, checkpoint = tmp_path / "policy", tmp_path / "ckpt"
    shutil.copytree(policy_world.exported, folder)
    manifest = json.loads((folder / "manifest.json").read_text())
    assert set(manifest["spec"]["max_step"]) == {"x", "y", "z", "qx", "qy", "qz", "qw"}
    manifest["spec"]["max_step"] = tight
    (folder / "manifest.json").write_text(json.dumps(manifest))
    shutil.copytree(policy_world.checkpoint, checkpoint)
    config = json.loads((checkpoint / CONFIG_FILE).read_text())
    config["max_step"] = tight
    config[CHECKSUM_KEY] = config_checksum({k: v for k, v in config.items() if k != CHECKSUM_KEY})
    (checkpoint / CONFIG_FILE).write_text(json.dumps(config))
    switching = ConditioningPolicy(first_expert="sample", switch_margin=0.0, switch_window=0)
    jumps = []

    def switches(policy, path: Path, seed: int) -> int:
        policy.reset(seed=seed)
        found = 0
        for observation in observations(read_demonstration(path), path):
            result = policy.step(observation)
            if result.switch is not None:
                found += 1
                jumps.append(np.abs(result.waypoints[0, :3] - observation[STATE_KEY][:3]).max())
        return found

    exported = load_policy(folder, threads=1, conditioning=switching)
    recordings = sorted(policy_world.demos.parent.glob("*/*.mcap"))
    counted = {(p, seed): switches(exported, p, seed) for seed, p in enumerate(recordings)}
    path, seed = max(counted, key=counted.get)
    assert counted[path, seed] >= 1, counted
    torch_policy = checkpoint_policy(
        checkpoint, policy_world.extractor, backend="eager", threads=1, conditioning=switching
    )
    assert switches(torch_policy, path, seed) >= 1
    assert max(jumps) <= 0.02 + 1e-6, jumps
