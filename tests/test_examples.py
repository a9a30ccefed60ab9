"""The example scripts run and report what their docstrings promise."""

import importlib.util
from pathlib import Path

import numpy as np

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def load(name: str):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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
