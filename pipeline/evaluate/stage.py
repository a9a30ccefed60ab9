"""Stage `evaluate`: the paper's tables (comparison, loss ablation, number of experts), the commitment
table (conditioned only on points several modes share) and figures, measured.

Every table is a grid of rows (methods) by columns (synthetic sets). For each (set, seed) the
baselines (ProMP, GMM-GMR with and without ridge, nearest demonstration) and every network the table
needs (CNEP variants, the parameter-matched CNMP) are fitted and scored on the same queries under
every protocol (see pipeline.evaluate.jobs and docs/concepts.md). A network that several tables
use (e.g. the comparison's CNEP is the ablation's CNEP and CNEP-MoE) is trained once.

Each cell is the mean +- std over all queries of all seeds (pooled), MSE and MAE, and the mode
accuracy as mean +- std over seeds. Outputs, written atomically into `out`:
    <table>.md, <table>.json      the measured tables, the paper's numbers beside ours, settings, times
    figures/<table>-<set>.png     demonstrations, conditioning points, generated trajectories
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from cnep.models.assignments import ASSIGNMENTS
from cnep.outputs import output_lock, writing_as
from cnep.pipeline.contract import check_writable_folder, output_folder, refuse_existing
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.addresses import check_executor
from cnep.pipeline.evaluate.constants import (
    CNEP_EXPERTS,
    DEFAULT_OUT,
    EXPERT_COUNTS,
    JOBS,
    LOCAL,
    PATIENCE,
    QUERIES,
    QUICK_QUERIES,
    QUICK_SEEDS,
    QUICK_SETS,
    QUICK_STEPS,
    SEEDS,
    STEPS,
    TABLE_SETS,
    TABLES,
    UNIT_NETWORKS,
)
from cnep.pipeline.evaluate.jobs import PROTOCOLS, Job, ModelSpec, run_unit, unit_key
from cnep.pipeline.evaluate.pool import as_finished
from cnep.pipeline.inputs import coerce_paths

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvaluateConfig:
    """tables: names from TABLES; seeds/steps/queries: None takes the full or quick default.

    sets: restrict the tables' columns (None: every set of each table, or QUICK_SETS with `quick`);
    patience: validations without improvement before a network stops early (None: every network trains all
    its steps); jobs: worker processes (0 runs everything in this process); force: replace tables already in `out`;
    executor: `local` (the process pool of `jobs`), `dask` or `ray` (pipeline.evaluate.executors), at `address`
    (None: a cluster of `jobs` processes on this machine).
    """

    tables: tuple[str, ...] = ("comparison",)
    quick: bool = False
    seeds: int | None = None
    steps: int | None = None
    queries: int | None = None
    sets: tuple[str, ...] | None = None
    patience: int | None = PATIENCE
    out: Path = Path(DEFAULT_OUT)
    jobs: int = JOBS
    figures: bool = True
    force: bool = False
    quiet: bool = False
    executor: str = LOCAL
    address: str | None = None

    def __post_init__(self) -> None:
        coerce_paths(self)
        check_executor(self.executor, self.address)
        unknown = [t for t in self.tables if t not in TABLES]
        if unknown or not self.tables:
            raise PipelineError(f"unknown table(s) {unknown or self.tables}; choose from {', '.join(TABLES)} or all")
        for name in ("seeds", "steps", "queries", "patience"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise PipelineError(f"--{name} must be >= 1, got {value}")
        empty = [t for t in self.tables if not self.table_sets(t)]
        if empty:
            raise PipelineError(
                f"no data set left for the {', '.join(empty)} table(s): it covers "
                f"{', '.join(TABLE_SETS[empty[0]])}, the run asked for {', '.join(self.sets or QUICK_SETS)}"
            )
        if self.jobs < 0:
            raise PipelineError(f"--jobs must be >= 0 (0: no worker processes), got {self.jobs}")

    @property
    def n_seeds(self) -> int:
        return self.seeds or (QUICK_SEEDS if self.quick else SEEDS)

    def n_steps(self, set_name: str) -> int:
        return self.steps or (QUICK_STEPS if self.quick else STEPS[set_name])

    def steps_by_set(self) -> dict[str, int]:
        sets = dict.fromkeys(s for table in self.tables for s in self.table_sets(table))
        return {s: self.n_steps(s) for s in sets}

    @property
    def n_queries(self) -> int:
        return self.queries or (QUICK_QUERIES if self.quick else QUERIES)

    def table_sets(self, table: str) -> tuple[str, ...]:
        keep = self.sets if self.sets is not None else QUICK_SETS if self.quick else None
        return tuple(s for s in TABLE_SETS[table] if keep is None or s in keep)


@dataclass(frozen=True)
class Row:
    """A table row on one set: its label, the network it needs (None: the baselines' job), its result name."""

    label: str
    spec: ModelSpec | None
    method: str


def table_rows(table: str, set_name: str) -> list[Row]:
    d = CNEP_EXPERTS[set_name]
    cnep = ModelSpec.of(d)
    nearest = Row("Nearest demo", None, "Nearest demo")
    if table == "comparison":
        baselines = [Row(name, None, name) for name in ("ProMP", "GMM-GMR", "GMM-GMR (no ridge)")]
        return baselines + [Row("CNMP", ModelSpec.of(1), "cnmp"), Row("CNEP", cnep, cnep.key), nearest]
    if table == "ablation":
        variants = {
            "CNEP-Uni": ModelSpec.of(d, a_batch=0.0),
            "CNEP-UnSpec": ModelSpec.of(d, a_ind=0.0),
            "CNEP-Rec": ModelSpec.of(d, a_batch=0.0, a_ind=0.0),
        }
        rows = [Row(label, spec, spec.key) for label, spec in variants.items()]
        return rows + [Row("CNEP-MoE", cnep, cnep.key + "+moe"), Row("CNEP", cnep, cnep.key), nearest]
    if table == "commitment":
        rows = [Row(name, None, name) for name in ("ProMP", "GMM-GMR")] + [Row("CNMP", ModelSpec.of(1), "cnmp")]
        for assignment in ASSIGNMENTS:
            spec = ModelSpec.of(d, assignment=assignment)
            rows += [
                Row(f"CNEP ({assignment})", spec, spec.key),
                Row(f"CNEP-MoE ({assignment})", spec, spec.key + "+moe"),
            ]
        return rows + [nearest]
    return [Row(f"CNEP-{k}", ModelSpec.of(k), ModelSpec.of(k).key) for k in EXPERT_COUNTS] + [nearest]


def plan(config: EvaluateConfig) -> list[Job]:
    """Every job the tables need, each once: the first table's jobs first (so it is written first), and
    within a table the most expensive first (workers finish together)."""
    jobs: dict[tuple, tuple[int, Job]] = {}
    for rank, table in enumerate(config.tables):
        for set_name in config.table_sets(table):
            for seed in range(config.n_seeds):
                for row in table_rows(table, set_name):
                    job = Job(
                        set_name,
                        seed,
                        row.spec,
                        config.n_steps(set_name),
                        config.n_queries,
                        cnmp_matches=CNEP_EXPERTS[set_name],
                        patience=config.patience,
                    )
                    jobs.setdefault(job.key, (rank, job))
    cost = {job: (rank, 0 if job.spec is None else -job.spec.n_experts) for rank, job in jobs.values()}
    return sorted(cost, key=cost.get)


def needs(table: str, config: EvaluateConfig) -> set[tuple]:
    """The (set, seed, spec) keys of the jobs a table reads."""
    return {
        (s, seed, row.spec)
        for s in config.table_sets(table)
        for seed in range(config.n_seeds)
        for row in table_rows(table, s)
    }


def units(jobs: Sequence[Job]) -> list[tuple[Job, ...]]:
    """Jobs in units of work, in plan order: network jobs of one `unit_key` (seeds, loss ablations, assignments of
    one network on one set) together, up to UNIT_NETWORKS, each unit placed where its first job was; baselines alone."""
    out: list[list[Job]] = []
    open_units: dict[tuple, list[Job]] = {}
    for job in jobs:
        key = unit_key(job)
        unit = open_units.get(key) if key is not None else None
        if unit is None or len(unit) == UNIT_NETWORKS:
            unit = []
            out.append(unit)
            if key is not None:
                open_units[key] = unit
        unit.append(job)
    return [tuple(unit) for unit in out]


def run_jobs(
    jobs: Sequence[Job], workers: int, quiet: bool, executor: str = LOCAL, address: str | None = None
) -> Iterator[tuple[Job, dict]]:
    """Yield (job, result) as jobs finish, in `units` of work run by `workers` spawned processes with one thread each
    (or here when 0), or on a Dask or Ray cluster (`executor`, `address`: pipeline.evaluate.executors), through
    pipeline.evaluate.pool.

    The bar counts training steps (every network's planned steps; an early stop credits the rest), so it
    moves while networks train and its time left is an estimate from the steps' rate; the units done and
    the last one finished follow it.
    """
    by_label = {"+".join(job.label for job in unit): unit for unit in units(jobs)}
    calls = {label: partial(run_unit, unit) for label, unit in by_label.items()}
    total = sum(job.steps for job in jobs if job.spec is not None)
    finished = as_finished(calls, total, "evaluate", workers, quiet, executor, address, unit="step", noun="units")
    for label, results in finished:
        for job, result in zip(by_label[label], results):
            log.debug("done %s", job.label)
            yield job, result


def pooled(per_seed: Sequence[dict]) -> dict:
    """Combine per-seed scores (each over the same number of queries) into mean +- std over all queries."""
    cell: dict = {}
    for metric in ("mse", "mae"):
        means = np.array([r[metric] for r in per_seed])
        second = np.array([r[f"{metric}_std"] ** 2 + r[metric] ** 2 for r in per_seed])
        cell[metric] = float(means.mean())
        cell[f"{metric}_std"] = float(np.sqrt(max(0.0, second.mean() - means.mean() ** 2)))
    accuracy = np.array([r["mode_accuracy"] for r in per_seed])
    cell["mode_accuracy"] = float(accuracy.mean())
    cell["mode_accuracy_std"] = float(accuracy.std())
    cell["failures"] = int(sum(r["failures"] for r in per_seed))
    cell["per_seed"] = [dict(r) for r in per_seed]
    return cell


def pooled_commitment(per_seed: Sequence[dict]) -> dict:
    """Combine per-seed commitment scores (models.evaluation.commitment): the valid share over all queries
    (and per seed), MSE and max deviation as mean +- std over all finite queries (each seed weighted by them)."""
    queries = np.array([r["queries"] for r in per_seed])
    finite = queries - np.array([r["failures"] for r in per_seed])
    cell: dict = {
        "valid": float(np.sum([r["valid"] * n for r, n in zip(per_seed, queries)]) / queries.sum()),
        "valid_per_seed": [r["valid"] for r in per_seed],
        "queries": queries.tolist(),
        "band": [r["band"] for r in per_seed],
        "failures": int(queries.sum() - finite.sum()),
    }
    for metric in ("mse", "max_deviation"):
        keep = finite > 0
        means = np.array([r[metric] for r in per_seed])[keep]
        second = np.array([r[f"{metric}_std"] ** 2 + r[metric] ** 2 for r in per_seed])[keep]
        w = finite[keep] / finite[keep].sum() if keep.any() else np.zeros(0)
        cell[metric] = float(w @ means) if keep.any() else float("nan")
        cell[f"{metric}_std"] = float(np.sqrt(max(0.0, w @ second - cell[metric] ** 2))) if keep.any() else float("nan")
    return cell


def assemble(table: str, config: EvaluateConfig, done: dict[tuple, dict]) -> dict:
    """The table as a JSON-ready dict: results[protocol][row][set] = pooled cell, training[row][set].

    `done` maps Job.key -> that job's results.
    """
    sets = config.table_sets(table)
    results = {p: {} for p in PROTOCOLS}
    training: dict = {}
    labels: list[str] = []
    for set_name in sets:
        for row in table_rows(table, set_name):
            labels += [row.label] if row.label not in labels else []
            runs = [done[(set_name, seed, row.spec)][row.method] for seed in range(config.n_seeds)]
            for p in PROTOCOLS:
                results[p].setdefault(row.label, {})[set_name] = pooled([r[p] for r in runs])
            if table == "commitment":
                results.setdefault("commitment", {}).setdefault(row.label, {})[set_name] = pooled_commitment(
                    [r["commitment"] for r in runs]
                )
            training.setdefault(row.label, {})[set_name] = {
                "fit_seconds": [r["fit_seconds"] for r in runs],
                **(
                    {
                        "best_val_error": [r["best_val_error"] for r in runs],
                        "final_usage": [r["final_usage"] for r in runs],
                        "steps": [r["steps"] for r in runs],
                        "val_curve": [r["val_curve"] for r in runs],
                        "parameters": runs[0]["parameters"],
                        "expert_widths": runs[0]["expert_widths"],
                    }
                    if row.spec is not None
                    else {}
                ),
            }
    return {
        "table": table,
        "sets": list(sets),
        "rows": labels,
        "settings": {
            "seeds": config.n_seeds,
            "steps": {s: config.n_steps(s) for s in sets},
            "queries": config.n_queries,
            "patience": config.patience,
            "quick": config.quick,
            "jobs": config.jobs,
        },
        "results": results,
        "training": training,
    }


def examples(table: str, done: dict[tuple, dict], set_name: str) -> dict[str, np.ndarray]:
    """Row label -> generated trajectories (k, T, dy) on the first paper (commitment) queries of seed 0."""
    key = "commitment_examples" if table == "commitment" else "examples"
    return {row.label: done[(set_name, 0, row.spec)][row.method][key] for row in table_rows(table, set_name)}


@writing_as("evaluate")
def evaluate(config: EvaluateConfig) -> dict[str, Path]:
    """Run the tables; returns {table: path of its Markdown file} (JSON and figures beside it).

    Each table is written as soon as all its jobs are done, so a long run yields its first table early.
    """
    start = time.perf_counter()
    jobs = plan(config)
    log.info(
        "evaluate: %d fits in %d units of work (%s), steps %s, %d seed(s), %d queries per protocol, %d worker(s)",
        len(jobs),
        len(units(jobs)),
        ", ".join(config.tables),
        config.steps_by_set(),
        config.n_seeds,
        config.n_queries,
        config.jobs,
    )
    tables = [config.out / f"{table}{suffix}" for table in config.tables for suffix in (".md", ".json")]
    if config.figures:
        tables += [
            figure_path(config, table, set_name) for table in config.tables for set_name in config.table_sets(table)
        ]
    refuse_existing(tables, config.force, "table or figure")
    pending = {table: needs(table, config) for table in config.tables}
    done: dict[tuple, dict] = {}  # Job.key -> results
    written = {}
    with output_folder(config.out), output_lock(config.out, folder=True):
        check_writable_folder(config.out)
        refuse_existing(tables, config.force, "table or figure")  # again, under the lock
        for job, result in run_jobs(jobs, config.jobs, config.quiet, config.executor, config.address):
            done[job.key] = result
            for table in [t for t, keys in pending.items() if not keys - done.keys()]:
                del pending[table]
                written[table] = write_table(table, config, done, time.perf_counter() - start)
                log.info("%s table written to %s", table, written[table])
    return {table: written[table] for table in config.tables}


def figure_path(config: EvaluateConfig, table: str, set_name: str) -> Path:
    """Where the figure of `table` on `set_name` goes."""
    return config.out / "figures" / f"{table}-{set_name}.png"


def write_table(table: str, config: EvaluateConfig, done: dict[tuple, dict], wall: float) -> Path:
    """Write <table>.md, <table>.json and the table's figures; returns the Markdown path."""
    from cnep.pipeline.evaluate.tables import PAPER_NOTE, to_markdown, write_text

    data = assemble(table, config, done)
    data["wall_seconds"] = wall
    data["paper_note"] = PAPER_NOTE
    write_text(config.out / f"{table}.json", _json(data))
    markdown = config.out / f"{table}.md"
    write_text(markdown, to_markdown(data))
    if config.figures:
        from cnep.pipeline.evaluate.figures import plot_set

        for set_name in config.table_sets(table):
            plot_set(
                figure_path(config, table, set_name),
                set_name,
                config.n_queries,
                examples(table, done, set_name),
                title=f"{table}: {set_name}",
                protocol="commitment" if table == "commitment" else "paper",
            )
    return markdown


def _json(data: dict) -> str:
    import json

    def clean(x):
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if isinstance(x, float) and not np.isfinite(x):
            return None  # JSON has no NaN: a failed cell is null
        return x

    return json.dumps(clean(data), indent=1)
