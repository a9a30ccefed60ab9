"""The units of work of `cnep evaluate`: one job fits one method family on one (set, seed) and scores it.

A job is picklable and self-contained, so it runs the same in this process or in a worker process
(spawned with one BLAS and one torch thread). A network job trains one network (models.fit's steps,
driven in chunks of REPORT_STEPS so that the caller's bar moves while it trains; the same
model as one `fit` call). Network jobs of one shape and schedule on one set (`unit_key`: the seeds,
loss ablations and assignments of one network) run as a unit of up to UNIT_NETWORKS, trained as one
batched computation (models.batched.BatchedTrainer; each network bit-identical to training it alone,
pipeline/evaluate/constants.py for what it saves). Every job of a (set, seed) builds the same data and the
Every job of a (set, seed) builds the same data and the
same queries from the seed, so all methods are scored on identical queries:

    data        models.synthetic.make_set(set, seed)
    paper       paper_queries(train, train_modes, n, seed)                 scored against the training pool
    heldout     heldout_queries(train, train_modes, test, test_modes, n, seed)
    commitment  shared_queries(train, train_modes): every point two or more modes share (no draws; none on
                the unimodal set)

Results: {method name: {"paper": scores, "heldout": scores, "commitment": `models.evaluation.commitment`'s
dict, "examples" / "commitment_examples": (k, T, dy) generated for the first k paper / commitment queries,
"fit_seconds": float, ...}} where scores is `models.evaluation.score`'s dict plus "failures" (queries
whose output was not finite).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cnep.models.config import CNEPConfig
from cnep.models.threads import SMALL_MODEL_THREADS
from cnep.pipeline.evaluate.constants import (
    GMM_COMPONENTS,
    PAPER_NLL_BETA,
    PROMP_WEIGHTS,
    REPORT_STEPS,
    SAMPLES_IN_FIGURE,
)
from cnep.pipeline.progress import RemoteBar

PROTOCOLS = ("paper", "heldout")


@dataclass(frozen=True)
class ModelSpec:
    """One trained network: its model config (one expert: the CNMP with the parameter count of a CNEP of
    `Job.cnmp_matches` experts)."""

    model: CNEPConfig

    @classmethod
    def of(cls, n_experts: int, **loss: object) -> ModelSpec:
        """The paper's CNEP with `n_experts` and `loss`'s changes to it (a_batch, a_ind, assignment)."""
        return cls(CNEPConfig(n_experts=n_experts, **{"assignment": "paper", **loss}))

    @property
    def n_experts(self) -> int:
        return self.model.n_experts

    @property
    def key(self) -> str:
        if self.n_experts == 1:
            return "cnmp"
        tags = [f"d{self.n_experts}"] + [f"{n}0" for n in ("a_batch", "a_ind") if getattr(self.model, n) == 0]
        tags += [] if self.model.assignment == "paper" else [self.model.assignment]
        return "cnep-" + "-".join(tags)


@dataclass(frozen=True)
class Job:
    """Fit `spec` (a ModelSpec, or None for all baselines) on `set_name` with `seed`, then score it."""

    set_name: str
    seed: int
    spec: ModelSpec | None
    steps: int
    n_queries: int
    cnmp_matches: int = 2  # a CNMP gets the parameter count of a CNEP with this many experts
    patience: int | None = None  # models.TrainConfig.patience: validations without improvement before stopping

    @property
    def key(self) -> tuple:
        """What identifies the fit: (set, seed, spec); steps and queries are the same for a whole run."""
        return self.set_name, self.seed, self.spec

    @property
    def label(self) -> str:
        return f"{self.set_name}/seed{self.seed}/{self.spec.key if self.spec else 'baselines'}"


def queries(set_name: str, seed: int, n: int):
    """The data set and every protocol's queries of a (set, seed): (SyntheticSet, {protocol: [query]})."""
    from cnep.models.evaluation import heldout_queries, paper_queries, shared_queries
    from cnep.models.synthetic import make_set

    s = make_set(set_name, seed)
    return s, {
        "paper": paper_queries(s.train, s.train_modes, n, seed),
        "heldout": heldout_queries(s.train, s.train_modes, s.test, s.test_modes, n, seed),
        "commitment": shared_queries(s.train, s.train_modes),
    }


def _scored(generate, s, qs: dict) -> dict:
    """Score one method on every protocol, counting queries whose output is not finite."""
    from cnep.models.evaluation import commitment, score

    failures = dict.fromkeys(PROTOCOLS, 0)

    def guarded(protocol):
        def run(obs_t, obs_y, query_t):
            out = np.asarray(generate(obs_t, obs_y, query_t), dtype=np.float64)
            failures[protocol] += int(not np.isfinite(out).all())
            return out

        return run

    result = {}
    for p in PROTOCOLS:
        scores = score(guarded(p), qs[p], s.train, s.train_modes)
        if failures[p]:  # a non-finite output has no nearest demonstration: no mode accuracy either
            scores["mode_accuracy"] = float("nan")
        result[p] = {**scores, "failures": failures[p]}
    T = s.steps
    times = np.arange(T) / (T - 1)
    result["examples"] = np.stack([generate(q.obs_t, q.obs_y, times) for q in qs["paper"][:SAMPLES_IN_FIGURE]])
    if qs["commitment"]:  # a set whose modes share no point (unimodal) has no commitment queries
        result["commitment"] = commitment(generate, qs["commitment"], s.train, s.train_modes)
        result["commitment_examples"] = np.stack(
            [generate(q.obs_t, q.obs_y, times) for q in qs["commitment"][:SAMPLES_IN_FIGURE]]
        )
    return result


def baselines(set_name: str, seed: int) -> dict:
    """name -> unfitted baseline, with the authors' sizes for this set (see pipeline.evaluate.constants)."""
    from cnep.models.baselines import GMMGMR, NearestDemo, ProMP

    return {
        "ProMP": ProMP(PROMP_WEIGHTS[set_name]),
        "GMM-GMR": GMMGMR(GMM_COMPONENTS[set_name], seed=seed),
        "GMM-GMR (no ridge)": GMMGMR(GMM_COMPONENTS[set_name], ridge=0.0, seed=seed),
        "Nearest demo": NearestDemo(),
    }


def model_config(spec: ModelSpec, cnmp_matches: int) -> CNEPConfig:
    from cnep.models import matched_cnmp

    if spec.n_experts == 1:
        return matched_cnmp(CNEPConfig(n_experts=cnmp_matches, assignment="paper"))  # the paper's CNMP
    return spec.model


def unit_key(job: Job) -> tuple | None:
    """Network jobs with equal keys train together (one network shape and schedule on one set); None: a baselines
    job."""
    if job.spec is None:
        return None
    return (
        job.set_name,
        job.steps,
        job.patience,
        job.spec.n_experts,
        job.cnmp_matches if job.spec.n_experts == 1 else None,
    )


def run_job(job: Job, bar: RemoteBar | None = None) -> dict:
    """Fit and score one job; returns {method name: results} (see the module docstring and `run_unit`)."""
    return run_unit((job,), bar=bar)[0]


def run_unit(unit: Sequence[Job], *, bar: RemoteBar | None = None) -> list[dict]:
    """Fit and score every job of `unit` (one baselines job, or network jobs of one `unit_key`); returns each
    job's {method name: results}, in order.

    Networks report on `bar` the number of steps they have trained so far (summed over the unit) every
    REPORT_STEPS steps (at most every REPORT_INTERVAL_S of pipeline.progress), and at the end, finally, all the
    steps they were planned (an early stop credits those it skipped), so that the bar reaches the jobs' steps.
    """
    import torch

    torch.set_num_threads(SMALL_MODEL_THREADS)
    if len({unit_key(job) for job in unit}) != 1 or (unit_key(unit[0]) is None and len(unit) > 1):
        raise ValueError(f"not one unit of work: {[job.label for job in unit]}")
    data = [queries(job.set_name, job.seed, job.n_queries) for job in unit]
    if unit[0].spec is not None:
        return _fit_networks(unit, data, bar)
    ((s, qs),) = data
    out = {}
    for name, method in baselines(unit[0].set_name, unit[0].seed).items():
        start = time.perf_counter()
        method.fit(s.train)
        fit_seconds = time.perf_counter() - start
        out[name] = {**_scored(method.generate, s, qs), "fit_seconds": fit_seconds}
    return [out]


def _fit_networks(unit: Sequence[Job], data: list, bar: RemoteBar | None) -> list[dict]:
    """Train the unit's networks as `models.fit` does (each validated on its set's validation split), together,
    reporting steps, and score each. fit_seconds: the unit's training time over its number of networks."""
    from cnep.models import TrainConfig
    from cnep.models.batched import BatchedTrainer
    from cnep.models.train import finish_fit, prepare_fit

    start = time.perf_counter()
    configs = [model_config(job.spec, job.cnmp_matches) for job in unit]
    prepared = [
        prepare_fit(
            list(s.train),
            config,
            TrainConfig(steps=job.steps, patience=job.patience, seed=job.seed, nll_beta=PAPER_NLL_BETA),
            list(s.val),
        )
        for job, (s, _), config in zip(unit, data, configs)
    ]
    trainer = BatchedTrainer([t for t, _ in prepared])
    planned, trained = sum(job.steps for job in unit), lambda: sum(t.step for t, _ in prepared)
    while trainer.active and trainer.step < unit[0].steps:
        trainer.run(until=trainer.step + REPORT_STEPS)
        if bar is not None:
            bar.update(trained())
    if bar is not None:
        bar.update(planned, final=True)
    fit_seconds = (time.perf_counter() - start) / len(unit)
    return [
        _scored_network(job, s, qs, config, *finish_fit(t, split), fit_seconds, t.step, t.best_error)
        for job, (s, qs), config, (t, split) in zip(unit, data, configs, prepared)
    ]


def _scored_network(
    job: Job, s, qs: dict, config, model, history: list[dict], fit_seconds: float, steps: int, best_val_error: float
) -> dict:
    """A fitted network's results: winner-take-all (and for CNEPs the mixture) on both protocols, with training info
    (`steps`: the steps it trained, fewer than job.steps after an early stop; `val_curve`: (step, validation error);
    `best_val_error`: the kept model's, models.train.Trainer.best_error)."""
    info = {
        "fit_seconds": fit_seconds,
        "steps": steps,
        "val_curve": [(h["step"], h["val_error"]) for h in history],
        "best_val_error": best_val_error,
        "final_usage": history[-1]["usage"],
        "parameters": sum(p.numel() for p in model.parameters()),
        "expert_widths": list(config.expert_widths),
    }

    def wta(obs_t, obs_y, query_t):
        return model.generate(obs_t, obs_y, query_t).mean

    def moe(obs_t, obs_y, query_t):
        return model.generate(obs_t, obs_y, query_t, mixture=True).mean

    out = {job.spec.key: {**_scored(wta, s, qs), **info}}
    if job.spec.n_experts > 1:
        out[job.spec.key + "+moe"] = {**_scored(moe, s, qs), **info}
    return out
