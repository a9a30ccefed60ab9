"""The example scripts run and report what their docstrings promise."""

import importlib.util
from pathlib import Path

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
