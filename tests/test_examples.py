"""The example scripts run and report what their docstrings promise."""

import csv
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load(name: str):
    if str(EXAMPLES) not in sys.path:  # as `python examples/NAME.py` runs it: the examples import each other
        sys.path.insert(0, str(EXAMPLES))
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # as `python examples/NAME.py` runs it: dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_gate_ceiling_classifiers_learn_the_modes(capsys, one_thread):
    load("gate_ceiling").main(["--seeds", "1", "--steps", "300"])
    lines = capsys.readouterr().out.splitlines()
    summary = dict(line.split(" mean ") for line in lines if not line.startswith("seed "))
    assert [name.strip() for name in summary] == ["mean + linear", "mean + MLP", "concat + MLP", "flat MLP"]
    accuracies = [float(rest.split()[0]) for rest in summary.values()]
    assert all(0.8 <= a <= 1 for a in accuracies), accuracies  # chance is 0.25: the contexts carry the modes


def test_policy_timebase_compares_the_time_base_with_the_oracle_at_each_speed(policy_world, capsys):
    rows = load("policy_timebase").main([str(policy_world.exported), str(policy_world.heldout), "--speeds", "1", "1.2"])
    assert [(r["factor"], r["time_base"]) for r in rows] == [
        (1.0, "time base"), (1.0, "oracle"), (1.2, "time base"), (1.2, "oracle")
    ]  # fmt: skip
    assert rows[0]["rmse_cm"] == rows[1]["rmse_cm"] and rows[0]["same_expert"] == 1.0  # at 1x the two agree
    assert all(np.isfinite(r["rmse_cm"]) and 0 <= r["same_expert"] <= 1 for r in rows)
    assert "| 1.20 | oracle |" in capsys.readouterr().out


def test_policy_parity_finds_the_exported_policy_equal_to_the_torch_one(policy_world, capsys, one_thread):
    w = policy_world
    found = load("policy_parity").main(
        [str(w.checkpoint), str(w.exported), str(w.heldout), "--extractor", str(w.extractor)]
    )
    assert set(found) == {"fp32", "int8"} and found["fp32"]["steps"] > 0
    assert found["fp32"]["xyz_max"] < 1e-4 and found["fp32"]["expert"] == 0 and found["fp32"]["switch"] == 0
    assert "| fp32 |" in capsys.readouterr().out


def test_first_read_probes_separate_what_is_separable_and_nothing_else():
    probes = load("first_read").probe_accuracy
    rng = np.random.default_rng(0)
    labels = np.repeat(np.array(["a", "b", "c", "d"]), 100)  # (400,)
    rows = 5 * rng.normal(size=(4, 300))[np.repeat(np.arange(4), 100)] + rng.normal(size=(400, 300))  # (400, 300)
    train, test = (rows[::2], labels[::2]), {"test": (rows[1::2], labels[1::2])}  # fewer rows than columns
    assert probes(*train, test) == {"ridge": {"test": 1.0}, "1nn": {"test": 1.0}}
    shuffled = probes(train[0], rng.permutation(train[1]), test)
    assert all(0.1 < found["test"] < 0.4 for found in shuffled.values()), shuffled  # chance is 0.25


def test_first_read_measures_a_demo_folder_and_its_extra_scenes(quick_demo, tmp_path, capsys, one_thread):
    out, table = tmp_path / "first_read.json", tmp_path / "first_read.csv"
    found = load("first_read").main([str(quick_demo), "--extra", "2", "--json", str(out), "--csv", str(table)])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "---" not in line]
    assert [row.split(" | ")[0] for row in rows] == ["| seed", "| 0", "| mean (1)"]  # the header, a folder, the mean
    assert all(len(row.split(" | ")) == len(rows[0].split(" | ")) for row in rows)
    (f,) = json.loads(out.read_text())
    (header, row) = list(csv.reader(table.read_text().splitlines()))
    assert header[:3] == ["seed", "features ridge (held-out)", "features ridge (extra)"] and len(row) == len(header)
    assert header[-2:] == ["gate follows motion", "gate follows images"] and row[0] == "0"
    assert float(row[1]) == pytest.approx(f["features"]["ridge"]["heldout"], abs=0.005)
    assert f == found[0] and f["seed"] == 0 and f["n"] == {"train": 8, "heldout": 4, "extra": 8}  # 2 per behaviour
    accuracies = [
        *(f["features"][probe] for probe in ("ridge", "1nn", "side", "slot")),
        *(f["latent"][model][probe] for model in ("CNEP", "CNMP") for probe in ("ridge", "1nn")),
        f["gate"],
        *f["path"].values(),
    ]
    assert all(set(a) == {"heldout", "extra"} and all(0 <= v <= 1 for v in a.values()) for a in accuracies)
    summary = json.loads((quick_demo / "summary.json").read_text())["heldout"]
    for model, row in summary.items():  # the path read is the demo summary's, scene for scene
        assert f["path"][model]["heldout"] == pytest.approx(1 - row["wrong_behaviour"] / row["n"])
    calibration = f["calibration"]
    assert calibration["reads"] == 12 and calibration["wrong"] == round(4 * (1 - f["gate"]["heldout"])) + round(
        8 * (1 - f["gate"]["extra"])
    )
    shares = [calibration[k] for k in ("p_wrong", "p_right", "confident_wrong", "unsure_wrong", "unsure_right")]
    assert all(v is None or 0 <= v <= 1 for v in shares)
    assert (calibration["p_wrong"] is None) == (calibration["wrong"] == 0)
    assert all(0 <= f["gate_follows"][by] <= 1 for by in ("motion", "images"))


def test_first_read_swaps_in_another_behaviours_motion_beside_the_scenes_images(quick_demo, monkeypatch, one_thread):
    module = load("first_read")
    labels = module.recorded_labels(quick_demo / "recorded")
    decided = [
        p
        for p in sorted((quick_demo / "trajectories" / "train").glob("*.mcap"))
        if labels[module.key(p)] in module.BEHAVIOURS
    ]
    train = module.read_scenes(decided, labels)
    heldout = module.read_scenes(sorted((quick_demo / "trajectories" / "heldout").glob("*.mcap")), labels)
    trained = module.load_trained(quick_demo / "checkpoints" / "cnep")
    a, b = trained.mapping.blocks["features"]
    experts = {behaviour: i for i, behaviour in enumerate(module.BEHAVIOURS)}

    def rows(scenes) -> list:  # (model rows, behaviour) of each scene
        return [(trained.rows(t, p), y) for t, p, y in zip(scenes.trajectories, scenes.sources, scenes.labels)]

    def follower(block, known: list):  # a gate that names the behaviour whose rows `block` shows
        return lambda model, mixed: np.eye(len(experts))[
            next(experts[label] for r, label in known if np.array_equal(r[: len(mixed), block], mixed[:, block]))
        ]

    motion = np.r_[0:a, b : trained.model.config.columns.width]
    monkeypatch.setattr(module, "gate_of", follower(motion, rows(train)))
    assert module.motion_or_images(trained, train, heldout, experts) == {"motion": 1.0, "images": 0.0}
    monkeypatch.setattr(module, "gate_of", follower(slice(a, b), rows(heldout)))
    assert module.motion_or_images(trained, train, heldout, experts) == {"motion": 0.0, "images": 1.0}


def test_first_read_refuses_a_folder_the_demo_did_not_make_before_any_work(quick_demo, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit:
        load("first_read").main([str(quick_demo), str(tmp_path)])
    printed = capsys.readouterr()
    assert exit.value.code == 2 and printed.out == ""  # nothing measured, not even the header
    assert f"{tmp_path}: no recorded, demos/train, " in printed.err


def test_switch_margin_applies_each_rule_to_the_demos_gates(quick_demo, capsys, one_thread):
    rows = load("switch_margin").main([str(quick_demo), "--scene-changes", "0"])
    argmax = rows[0]
    assert (argmax["margin"], argmax["window"], argmax["later"]) == (0.0, 0, 0)
    assert len(rows) == len(load("switch_margin").RULES) and "| 0.3 | 3 |" in capsys.readouterr().out
    for row in rows:  # a rule only hands over to the gate's leader: never more switches than the argmax
        assert sum(row["free_choice"]) <= sum(argmax["free_choice"]) and sum(row["heldout"]) <= sum(argmax["heldout"])


def test_demonstrators_reports_each_versions_scenes(capsys):
    pytest.importorskip("mujoco")
    rows = load("demonstrators").main(["--seeds", "1", "--versions", "1"])
    assert [(r["task"], r["scene"]) for r in rows] == load("demonstrators").SCENES
    assert all(r["version"] == 1 and r["episodes"] == 1 and r["success"] == 1 for r in rows)
    assert [r["changed"] for r in rows] == [0, 0, 1, 0, 1]  # the changed scene and the cue that shows
    assert "| pick-place | changed | v1 | 1 | 1 | 1 |" in capsys.readouterr().out


def test_grasp_probe_finds_the_first_step_its_gripper_command_reads_closed():
    from cnep.runtime.gripper import HIGH, GripperCommand

    grasp_step = load("grasp_probe").grasp_step
    opening = GripperCommand.from_levels(0.028, 0.08)  # an opening: the low value closes, below fall 0.041
    assert grasp_step(np.array([0.08, 0.08, 0.05, 0.03, 0.028]), opening) == 3  # 0.05 is within the hysteresis
    assert grasp_step(np.array([0.08, 0.06, 0.05, 0.08]), opening) is None
    command = GripperCommand.from_levels(0.0, 1.0, closed=HIGH)  # a command in [0, 1]: 1 closes, above rise 0.75
    assert grasp_step(np.array([0.0, 0.2, 0.7, 1.0, 1.0]), command) == 3


def test_grasp_probe_reads_a_checkpoint_on_its_held_out_demonstrations(quick_demo, tmp_path, capsys, one_thread):
    module = load("grasp_probe")
    out = tmp_path / "rows.json"
    checkpoint, held_out = quick_demo / "checkpoints" / "cnep", quick_demo / "trajectories" / "heldout"
    rows = module.main([str(checkpoint), str(held_out), "--before", "1", "--json", str(out)])
    assert json.loads(out.read_text()) == rows
    assert [r["read"] for r in rows] == ["the first step", "1 step before the grasp"]
    printed = capsys.readouterr().out.splitlines()
    assert len(printed) == 2 + len(rows) and printed[2].startswith("| the first step |")
    # The mean is the training demonstrations' mean grasp (config.json's training split), scored on the held-out ones.
    trained = module.load_trained(checkpoint)
    command = module.GripperCommand.from_dict(trained.config["gripper"])
    fitted = [Path(f["path"]) for f in trained.config["files"] if f["split"] == "train"]
    mean = np.mean([d.xy for d in module.demonstrations(fitted, trained, command)], axis=0)
    tests = module.demonstrations([held_out], trained, command)
    assert rows[0]["demonstrations"] == len(tests) == len(list(held_out.glob("*.mcap")))  # every demo scene grasps
    assert rows[0]["mean_cm"] == round(100 * float(np.median([np.linalg.norm(d.xy - mean) for d in tests])), 2)
    # The demo's behaviours grasp 20 cm apart, and the first frame shows which: the features locate the grasp.
    assert rows[0]["probe_cm"] < 0.5 * rows[0]["mean_cm"]
    assert all(np.isfinite(r["model_cm"]) and r["model_cm"] >= 0 for r in rows)


def test_grasp_probe_refuses_what_it_cannot_probe_in_one_line(quick_demo, tmp_path, capsys):
    module = load("grasp_probe")
    for argv, message in (
        ([str(tmp_path), str(quick_demo / "trajectories" / "heldout")], f"{tmp_path}/config.json: no checkpoint"),
        ([str(quick_demo / "checkpoints" / "cnep"), str(tmp_path)], f"{tmp_path}"),
    ):
        with pytest.raises(SystemExit) as exit:
            module.main(argv)
        printed = capsys.readouterr()
        assert exit.value.code == 2 and printed.out == ""
        assert message in printed.err and "Traceback" not in printed.err
