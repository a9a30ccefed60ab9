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


def test_the_quick_evaluate_benchmark_prints_each_rows_mode_accuracy_and_fails_unless_the_networks_separate(
    tmp_path, monkeypatch, capsys
):
    """bench_quick_evaluate: `cnep evaluate --quick` on the sets and steps asked (its run: quick_results, the command's
    evaluation, tests/pipeline/test_evaluate.py), a row per protocol, row and set, exit 1 unless the CNEP and the CNMP
    answer every query in its mode."""
    import benchmarks.bench_quick_evaluate as bench

    asked = []

    def results(sets, steps, out):
        asked.append((sets, steps, out))
        scores = {"mse": 0.01, "mode_accuracy": 1.0}
        by_row = {row: {name: dict(scores) for name in sets} for row in (*bench.ROWS, "ProMP")}
        return {"settings": {"seeds": 1, "steps": dict.fromkeys(sets, steps), "queries": 20}, "results": {
            protocol: {row: {name: dict(s) for name, s in by_set.items()} for row, by_set in by_row.items()}
            for protocol in (*bench.PROTOCOLS, "commitment")
        }}  # fmt: skip

    monkeypatch.setattr(bench, "quick_results", results)
    assert bench.main(["--sets", "bimodal", "multimodal", "--steps", "30", "--out", str(tmp_path)]) == 0
    assert asked == [(("bimodal", "multimodal"), 30, tmp_path)]
    printed = capsys.readouterr().out
    lines = [line for line in printed.splitlines() if line.startswith("| paper") or line.startswith("| heldout")]
    assert len(lines) == 2 * 3 * 2 and "| heldout | Nearest demo | multimodal | 0.0100 | 1.00 |" in lines
    assert "ProMP" not in printed and "the CNEP and the CNMP tell every mode apart" in printed
    data = results(("bimodal",), None, tmp_path)
    assert bench.separated(data)
    data["results"]["paper"]["Nearest demo"]["bimodal"]["mode_accuracy"] = 0.5  # not a network of the claim
    assert bench.separated(data)
    data["results"]["heldout"]["CNMP"]["bimodal"]["mode_accuracy"] = 0.95
    assert not bench.separated(data)
    monkeypatch.setattr(bench, "quick_results", lambda sets, steps, out: data)
    assert bench.main([]) == 1 and "do not tell every mode apart" in capsys.readouterr().out


def test_the_loops_episodes_dealt_to_processes_come_back_together_in_seed_order():
    from benchmarks.lerobot_loop import merged, shared_out

    parts = shared_out(list(range(5000, 5007)), 3)
    assert parts == [[5000, 5003, 5006], [5001, 5004], [5002, 5005]]
    assert shared_out([5000, 5001], 8) == [[5000], [5001]]  # no process without an episode
    rows = [{"all": [{"seed": s, "success": s % 2 == 0} for s in part]} for part in parts]
    assert [r["seed"] for r in merged(rows)["all"]] == list(range(5000, 5007))


def test_the_table_gives_one_cpu_threads_step_times_where_the_policy_ran_on_a_gpu(tmp_path):
    from benchmarks.bench_lerobot_policies import write_csv

    def rates(ms, **more):
        return {"episodes": 2, "success": 0.5, "success_ci": [0.1, 0.9], "collision": 0.0, "ms": ms, **more}

    gpu, one_thread = {"policy": {"p50": 4.0, "p99": 9.0}}, {"policy": {"p50": 30.0, "p99": 6000.0}}
    results = {
        "cnep": {"rates": {"all": rates({"policy": {"p50": 7.0, "p99": 12.0}}, entropy=0.9)}},
        "diffusion-features": {"training": {"steps": 10}, "rates": {"all": rates(gpu, cpu_ms=one_thread)}},
    }
    write_csv(results, tmp_path / "results.csv")
    lines = (tmp_path / "results.csv").read_text().splitlines()
    assert lines[1] == "cnep,all,2,0.5,0.1,0.9,0.0,0.9,7.0,12.0,,,"
    assert lines[2] == "diffusion-features,all,2,0.5,0.1,0.9,0.0,,30.0,6000.0,10,,"
