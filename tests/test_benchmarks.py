"""`python -m benchmarks` (what `make bench` runs) lists every benchmark and runs one by name."""

import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.__main__ import benchmarks, in_all, main

ROOT = Path(__file__).resolve().parents[1]


def test_the_list_names_every_benchmark_with_its_first_docstring_line(capsys):
    assert main([]) == 0
    listed = capsys.readouterr().out
    files = sorted(p.stem.removeprefix("bench_") for p in (ROOT / "benchmarks").glob("bench_*.py"))
    assert sorted(benchmarks()) == files and all(benchmarks().values())
    for name, line in benchmarks().items():
        assert f"{name}" in listed and line in listed


def test_all_leaves_out_the_benchmarks_that_take_hours_and_runs_the_rest(monkeypatch, capsys):
    import benchmarks.__main__ as runner

    ran = []
    monkeypatch.setattr(runner, "run", lambda name, options: ran.append(name) or 0)
    assert main(["all"]) == 0
    assert not in_all("lerobot_policies") and in_all("replay")
    assert "lerobot_policies" not in ran and sorted(ran) == sorted(n for n in benchmarks() if n != "lerobot_policies")
    assert "not in all (hours with their defaults; run each by name): lerobot_policies" in capsys.readouterr().out


def test_a_benchmark_runs_by_name_and_an_unknown_name_is_refused(capsys):
    done = subprocess.run(
        [sys.executable, "-m", "benchmarks", "recordings", "--help"], capture_output=True, text=True, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    assert "== recordings: -m benchmarks.bench_recordings --help" in done.stdout and "usage:" in done.stdout
    assert main(["nothing"]) == 2
    assert "no benchmark 'nothing'" in capsys.readouterr().err


@pytest.mark.slow
def test_the_commitment_benchmark_scores_a_short_fit_on_the_paper_s_sines():
    """benchmarks.paper_sines: seeded, modes alternating, every mode through the same start; bench_commitment's
    cell trains on what `fit` does not hold out and scores every shared point of it."""
    import numpy as np

    from benchmarks.bench_commitment import cell
    from benchmarks.paper_sines import PER_MODE, paper_sines

    y, modes = paper_sines(3, seed=4)
    again, _ = paper_sines(3, seed=4)
    assert y.shape == (3 * PER_MODE, 200, 1) and np.array_equal(y, again) and list(modes[:4]) == [0, 1, 2, 0]
    assert np.ptp([y[modes == k, 0].mean() for k in range(3)]) < 0.05 < np.ptp(y[:, 100])  # shared start, then apart
    row = cell("paper", 2, 0, {"steps": 20, "val_every": 10, "warmup_steps": 5})
    assert row["steps"] == 20 and row["experts"] == 2 and row["queries"] >= 2 and 0.0 <= float(row["valid"]) <= 1.0


@pytest.mark.slow
def test_the_quick_evaluate_benchmark_prints_each_rows_mode_accuracy_and_fails_unless_the_networks_separate(
    tmp_path, monkeypatch, capsys
):
    """bench_quick_evaluate runs `cnep evaluate --quick` (here with a few steps) and exits 1 unless the CNEP and the
    CNMP answer every query in its mode."""
    import json

    import torch

    import cnep.models.baselines.gmm as gmm_module
    from benchmarks.bench_quick_evaluate import main as bench
    from benchmarks.bench_quick_evaluate import rows, separated

    monkeypatch.setattr(gmm_module, "EM_ITERATIONS", 3)  # the GMM rows are not read here
    threads = torch.get_num_threads()
    try:
        status = bench(["--steps", "5", "--out", str(tmp_path)])
    finally:
        torch.set_num_threads(threads)  # the evaluation's jobs pin one thread
    printed = capsys.readouterr().out
    data = json.loads((tmp_path / "comparison.json").read_text())
    assert data["settings"]["quick"] and data["settings"]["steps"] == {"bimodal": 5} and data["sets"] == ["bimodal"]
    assert status == (0 if separated(data) else 1)
    found = rows(data)
    assert {(p, r) for p, r, *_ in found} == {
        (p, r) for p in ("paper", "heldout") for r in ("CNEP", "CNMP", "Nearest demo")
    }
    for protocol, row, name, mse, accuracy in found:
        assert f"| {protocol} | {row} | {name} | {mse:.4f} | {accuracy:.2f} |" in printed
    for protocol, row in (("paper", "CNEP"), ("heldout", "CNMP")):  # one network's query in another mode: no separation
        for results in (data["results"][p][r]["bimodal"] for p in ("paper", "heldout") for r in ("CNEP", "CNMP")):
            results["mode_accuracy"] = 1.0
        assert separated(data)
        data["results"][protocol][row]["bimodal"]["mode_accuracy"] = 0.95
        assert not separated(data)
