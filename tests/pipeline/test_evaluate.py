"""`cnep evaluate`: the plan, the pooled statistics, the tables' structure from a tiny run, and `--quick`."""

import json

import numpy as np
import pytest
import torch

import cnep.models.baselines.gmm as gmm_module
import cnep.pipeline.progress as progress
from cnep.pipeline.cli.main import main
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.constants import PAPER, QUICK_QUERIES, QUICK_SEEDS, QUICK_SETS, QUICK_STEPS, TABLES
from cnep.pipeline.evaluate.jobs import ModelSpec
from cnep.pipeline.evaluate.stage import EvaluateConfig, evaluate, plan, pooled, table_rows
from cnep.pipeline.progress import RemoteBar


def test_plan_trains_each_shared_network_once():
    config = EvaluateConfig(tables=TABLES, quick=True, seeds=2)
    jobs = plan(config)
    keys = [(j.set_name, j.seed, j.spec) for j in jobs]
    assert len(keys) == len(set(keys))
    # bimodal (d=2 CNEP) per seed: baselines, CNMP, CNEP-d2 (comparison, ablation's CNEP/MoE, experts' CNEP-2),
    # 3 ablation variants, CNEP-4 and CNEP-8, and the commitment table's CNEP-d2 with the mixture, the
    # annealed and the bounded assignment
    assert sum(j.set_name == "bimodal" for j in jobs) == 2 * 11
    assert {j.set_name for j in jobs} == {"bimodal", "multimodal"}


def test_steps_per_set_unless_given():
    by_set = {j.set_name: j.steps for j in plan(EvaluateConfig(tables=("comparison",)))}
    assert by_set["bimodal"] < by_set["multimodal"] == by_set["multimodal6"]
    assert {j.steps for j in plan(EvaluateConfig(tables=("comparison",), steps=123))} == {123}
    quick = plan(EvaluateConfig(quick=True))  # the comparison on QUICK_SETS, QUICK_SEEDS seeds, QUICK_QUERIES queries
    assert {(j.set_name, j.steps, j.n_queries) for j in quick} == {(s, QUICK_STEPS, QUICK_QUERIES) for s in QUICK_SETS}
    assert {j.seed for j in quick} == set(range(QUICK_SEEDS))


def test_patience_reaches_every_network_unless_turned_off():
    from cnep.pipeline.evaluate.constants import PATIENCE

    assert {j.patience for j in plan(EvaluateConfig(tables=("comparison",)))} == {PATIENCE}
    assert {j.patience for j in plan(EvaluateConfig(tables=("comparison",), patience=None))} == {None}


def test_rows_of_each_table():
    assert [r.label for r in table_rows("comparison", "bimodal")] == [
        "ProMP",
        "GMM-GMR",
        "GMM-GMR (no ridge)",
        "CNMP",
        "CNEP",
        "Nearest demo",
    ]
    ablation = {r.label: r for r in table_rows("ablation", "multimodal")}
    assert ablation["CNEP-Rec"].spec == ModelSpec.of(4, a_batch=0.0, a_ind=0.0)
    assert ablation["CNEP-MoE"].spec == ablation["CNEP"].spec and ablation["CNEP-MoE"].method.endswith("+moe")
    assert [r.spec.n_experts for r in table_rows("experts", "multimodal6") if r.spec] == [2, 4, 8]
    commitment = {r.label: r for r in table_rows("commitment", "multimodal6")}
    assert list(commitment) == [
        "ProMP",
        "GMM-GMR",
        "CNMP",
        "CNEP (paper)",
        "CNEP-MoE (paper)",
        "CNEP (mixture)",
        "CNEP-MoE (mixture)",
        "CNEP (annealed)",
        "CNEP-MoE (annealed)",
        "CNEP (bounded)",
        "CNEP-MoE (bounded)",
        "Nearest demo",
    ]
    assert commitment["CNEP (mixture)"].spec == ModelSpec.of(8, assignment="mixture")
    assert commitment["CNEP-MoE (paper)"].spec == commitment["CNEP (paper)"].spec == ModelSpec.of(8)


def test_pooled_equals_statistics_over_all_queries():
    rng = np.random.default_rng(0)
    errors = rng.random((3, 7))  # seeds x queries
    per_seed = [
        {"mse": e.mean(), "mse_std": e.std(), "mae": e.mean(), "mae_std": e.std(), "mode_accuracy": a, "failures": 0}
        for e, a in zip(errors, (0.5, 1.0, 0.75))
    ]
    cell = pooled(per_seed)
    assert cell["mse"] == pytest.approx(errors.mean())
    assert cell["mse_std"] == pytest.approx(errors.std())
    assert cell["mode_accuracy"] == pytest.approx(0.75)
    assert cell["mode_accuracy_std"] == pytest.approx(np.std([0.5, 1.0, 0.75]))


@pytest.fixture
def torch_threads():
    """run_job pins torch to one thread (it is meant for worker processes): restore the count afterwards."""
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


@pytest.mark.slow
def test_tiny_run_writes_every_table(tmp_path, monkeypatch, torch_threads):
    monkeypatch.setattr(gmm_module, "EM_ITERATIONS", 3)  # structure only: a few EM steps are enough
    config = EvaluateConfig(
        tables=TABLES, seeds=1, steps=8, queries=3, sets=("bimodal",), out=tmp_path, jobs=0, quiet=True
    )
    written = evaluate(config)
    assert set(written) == set(TABLES)
    for table in TABLES:
        data = json.loads((tmp_path / f"{table}.json").read_text())
        rows = [r.label for r in table_rows(table, "bimodal")]
        assert data["rows"] == rows and data["sets"] == ["bimodal"]
        for protocol in ("paper", "heldout"):
            for row in rows:
                cell = data["results"][protocol][row]["bimodal"]
                assert {"mse", "mse_std", "mae", "mae_std", "mode_accuracy", "failures"} <= set(cell)
                assert len(cell["per_seed"]) == 1
        nearest = data["results"]["paper"]["Nearest demo"]["bimodal"]
        assert nearest["mse"] == pytest.approx(0.0, abs=1e-12) and nearest["mode_accuracy"] == 1.0
        markdown = written[table].read_text()
        for by_set in PAPER.get(table, {}).values():
            if "bimodal" in by_set:
                assert f"(paper {by_set['bimodal'][0]:.3f}" in markdown
        assert (tmp_path / "figures" / f"{table}-bimodal.png").read_bytes()[:4] == b"\x89PNG"
    commitment = json.loads((tmp_path / "commitment.json").read_text())["results"]["commitment"]
    nearest = commitment["Nearest demo"]["bimodal"]  # returns a demonstration through the point: always valid
    assert nearest["valid"] == 1.0 and nearest["queries"] == [5] and nearest["max_deviation"] == 0.0
    assert set(commitment) == {r.label for r in table_rows("commitment", "bimodal")}
    assert "### Valid (share of all queries; per seed)" in written["commitment"].read_text()


def test_bad_arguments_are_one_line_errors(capsys):
    assert main(["evaluate", "--seeds", "0", "--out", "unused"]) == 2
    assert "--seeds must be >= 1" in capsys.readouterr().err
    assert main(["evaluate", "--table", "ablation", "--sets", "multimodal6", "--out", "unused"]) == 2
    assert "no data set left for the ablation table" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse names the choices
        main(["evaluate", "--sets", "trimodal"])


def test_sets_restrict_every_table():
    jobs = plan(EvaluateConfig(tables=("comparison", "experts"), sets=("multimodal6",), steps=10))
    assert {j.set_name for j in jobs} == {"multimodal6"}


@pytest.mark.slow  # networks trained in this process (the worker processes give the same results,
# test_a_cluster_gives_the_results_of_the_local_pool, and run in the progress test)
def test_quick_command_runs_the_comparison_on_its_sets_and_says_what_it_checks(
    tmp_path, capsys, monkeypatch, torch_threads
):
    """The command's behaviour with a few training steps and queries (its own counts: test_steps_per_set_unless_given);
    whether its 1500 steps tell the bimodal modes apart is measured by benchmarks/bench_quick_evaluate.py."""
    monkeypatch.setattr(gmm_module, "EM_ITERATIONS", 3)  # the GMM rows are not read here: a few EM steps
    argv = ["-q", "evaluate", "--quick", "--steps", "20", "--queries", "3", "--jobs", "0", "--no-figures"]
    assert main([*argv, "--out", str(tmp_path)]) == 0  # the figures: test_tiny_run_writes_every_table
    said = capsys.readouterr().out
    assert f"{QUICK_SEEDS} seed(s), 20 training steps, 3 queries per protocol" in said
    assert "does not reproduce the paper's ordering" in said
    data = json.loads((tmp_path / "comparison.json").read_text())
    settings = data["settings"]
    assert data["sets"] == list(QUICK_SETS) and settings["quick"] and settings["seeds"] == QUICK_SEEDS
    assert settings["steps"] == dict.fromkeys(QUICK_SETS, 20) and settings["queries"] == 3
    for name in QUICK_SETS:
        for protocol in ("paper", "heldout"):
            for row in ("CNEP", "CNMP"):
                assert 0.0 <= data["results"][protocol][row][name]["mode_accuracy"] <= 1.0
        nearest = data["results"]["paper"]["Nearest demo"][name]  # a demonstration's own points: it returns that one
        assert nearest["mse"] == pytest.approx(0.0, abs=1e-12) and nearest["mode_accuracy"] == 1.0


class _Reports:
    """The queue of a job's RemoteBar: the counts of trained steps it reports, in order."""

    def __init__(self):
        self.counts = []
        self.bar = RemoteBar(self, "unit")

    def put(self, report):
        _, n, _ = report
        self.counts.append(n)


@pytest.mark.slow
def test_a_network_job_reports_its_steps_and_trains_as_fit(monkeypatch, torch_threads):
    import cnep.pipeline.evaluate.jobs as jobs
    from cnep.models import TrainConfig, fit
    from cnep.models.synthetic import make_set
    from cnep.pipeline.evaluate.constants import PAPER_NLL_BETA
    from cnep.pipeline.evaluate.jobs import Job, model_config, run_job

    report_steps = 40  # a job's chunk of training (jobs.REPORT_STEPS), smaller: fewer steps, driven the same way
    monkeypatch.setattr(jobs, "REPORT_STEPS", report_steps)
    monkeypatch.setattr(progress, "REPORT_INTERVAL_S", 0.0)  # every chunk's report is sent
    job = Job("bimodal", 1, ModelSpec.of(2, assignment="bounded"), steps=report_steps + 30, n_queries=3)
    reports = _Reports()
    result = run_job(job, reports.bar)["cnep-d2-bounded"]
    # the steps trained after each chunk, then the final report of all the planned steps
    assert reports.counts == [report_steps, job.steps, job.steps] and result["steps"] == job.steps
    s = make_set("bimodal", 1)  # the same network trained by one models.fit call: the same validation curve
    _, history = fit(
        list(s.train),
        model_config(job.spec, job.cnmp_matches),
        TrainConfig(steps=job.steps, seed=1, nll_beta=PAPER_NLL_BETA),  # the paper's tables' likelihood
        list(s.val),
        progress=False,
    )
    assert result["val_curve"] == [(h["step"], h["val_error"]) for h in history]
    # the kept model's: the best from where the posterior settles (Assignment.settled_fraction) on
    assert result["best_val_error"] == min(h["val_error"] for h in history if h["step"] >= 0.8 * job.steps)


def test_units_group_one_network_shape_on_one_set():
    from cnep.pipeline.evaluate.constants import UNIT_NETWORKS
    from cnep.pipeline.evaluate.jobs import Job
    from cnep.pipeline.evaluate.stage import units

    jobs = [Job("bimodal", seed, ModelSpec.of(2, a_ind=a_ind), 40, 3) for seed in range(3) for a_ind in (None, 0.0)]
    jobs += [
        Job("bimodal", 0, None, 40, 3),
        Job("bimodal", 1, None, 40, 3),
        Job("bimodal", 0, ModelSpec.of(1), 40, 3),
        Job("multimodal", 0, ModelSpec.of(2), 40, 3),
        Job("bimodal", 0, ModelSpec.of(4), 40, 3),
    ]
    got = units(jobs)
    assert sorted(len(u) for u in got) == [1] * 5 + [UNIT_NETWORKS] * (6 // UNIT_NETWORKS)
    assert sorted(map(repr, (job for unit in got for job in unit))) == sorted(map(repr, jobs))  # each job once
    for unit in got:
        assert len({(j.set_name, j.spec and j.spec.n_experts) for j in unit}) == 1
        assert len(unit) == 1 or unit[0].spec is not None  # baselines alone


@pytest.mark.slow
def test_a_unit_trains_each_network_as_alone(torch_threads):
    from cnep.pipeline.evaluate.jobs import Job, run_job, run_unit

    unit = (Job("bimodal", 0, ModelSpec.of(2), 30, 3), Job("bimodal", 1, ModelSpec.of(2, assignment="annealed"), 30, 3))
    reports = _Reports()
    together = run_unit(unit, bar=reports.bar)
    assert reports.counts[-1] == 60
    for job, result in zip(unit, together):
        alone = run_job(job)
        for method, row in alone.items():
            assert row["val_curve"] == result[method]["val_curve"] and row["paper"] == result[method]["paper"]


def test_an_early_stop_credits_the_steps_it_skipped(monkeypatch, torch_threads):
    from cnep.models.train import Trainer
    from cnep.pipeline.evaluate.jobs import Job, run_job

    validate = Trainer.validate
    monkeypatch.setattr(Trainer, "validation_due", lambda self: True)  # validate after every step
    # the recorded error grows after the first validation (the best model stays the real one):
    # patience 2 stops at step 3
    monkeypatch.setattr(Trainer, "validate", lambda self: validate(self) + self.step)
    reports = _Reports()
    result = run_job(Job("bimodal", 0, ModelSpec.of(1), steps=150, n_queries=3, patience=2), reports.bar)["cnmp"]
    assert result["steps"] == 3 and [step for step, _ in result["val_curve"]] == [1, 2, 3]
    assert reports.counts == [3, 150]  # the steps it trained, then all it was planned: the bar reaches its total


@pytest.mark.slow
def test_progress_counts_training_steps_in_whole_lines(capsys, torch_threads):
    from cnep.pipeline.evaluate.jobs import Job
    from cnep.pipeline.evaluate.stage import run_jobs

    jobs = [
        Job("bimodal", 0, ModelSpec.of(2), steps=16, n_queries=3),
        Job("bimodal", 0, ModelSpec.of(1), steps=16, n_queries=3),
    ]
    assert [job for job, _ in run_jobs(jobs, workers=1, quiet=False)] != []
    lines = capsys.readouterr().err.splitlines()
    # two units (a CNEP and a CNMP do not train together)
    assert "\r" not in "".join(lines) and "32/32" in lines[-1] and "2/2 units" in lines[-1]


def test_unimodal_has_no_commitment_queries_and_still_scores(tmp_path, monkeypatch, torch_threads):
    monkeypatch.setattr(gmm_module, "EM_ITERATIONS", 3)
    config = EvaluateConfig(
        tables=("comparison",),
        seeds=1,
        steps=20,
        queries=3,
        sets=("unimodal",),
        out=tmp_path,
        jobs=0,
        quiet=True,
        figures=False,
    )
    evaluate(config)
    data = json.loads((tmp_path / "comparison.json").read_text())
    assert data["results"]["paper"]["CNEP"]["unimodal"]["failures"] == 0


@pytest.mark.slow  # starts a Dask cluster or a Ray instance of one worker process
@pytest.mark.parametrize("executor, package", [("dask", "distributed"), ("ray", "ray")])
def test_a_cluster_gives_the_results_of_the_local_pool(executor, package, torch_threads, tmp_path, monkeypatch):
    pytest.importorskip(package)
    from cnep.pipeline.evaluate.jobs import Job
    from cnep.pipeline.evaluate.stage import run_jobs

    monkeypatch.setenv("HOME", str(tmp_path))  # Ray keeps its session's token under HOME
    jobs = [Job("bimodal", 0, ModelSpec.of(2), 16, 3), Job("bimodal", 0, ModelSpec.of(1), 16, 3)]
    local = {job.key: result for job, result in run_jobs(jobs, workers=0, quiet=True)}
    on_cluster = {job.key: result for job, result in run_jobs(jobs, workers=1, quiet=True, executor=executor)}
    assert on_cluster.keys() == local.keys()
    for key, result in local.items():
        for method, row in result.items():
            remote = on_cluster[key][method]
            assert remote["paper"] == row["paper"] and remote["val_curve"] == row["val_curve"]


def test_an_executor_is_local_dask_or_ray_and_only_a_cluster_takes_an_address(tmp_path, capsys):
    with pytest.raises(PipelineError, match="unknown executor 'spark'"):
        EvaluateConfig(executor="spark")
    with pytest.raises(PipelineError, match="--executor local takes no address"):
        EvaluateConfig(address="tcp://host:8786")
    assert main(["evaluate", "--executor", "dask", "a", "b", "--out", str(tmp_path)]) == 2
    assert "--executor takes local, dask [ADDRESS] or ray [ADDRESS]" in capsys.readouterr().err
