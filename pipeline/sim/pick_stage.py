"""`cnep sim pick-place`: from nothing to the pick-and-place table, through the stages a user runs.

Stages (each logs its progress), all under OUT, as `cnep sim obstacle`'s (pipeline.sim.stage):

1. generate   `recorded/demo_NNN/` frames (PNG) + `poses.csv`: the scripted demonstrator picking the bar and
              putting it on a place the scene allows (pipeline.sim.generate);
2. ingest     `demos/`; 3. extract `trajectories/` and `extractor.pt`; 4. train `checkpoints/{cnep,cnmp}-seedN`;
5. export     `policies/{cnep,cnmp}-seedN`;
6. closed loop `episodes/*.rrd` (the first `record` episodes of each policy, protocol and condition) and
              `summary.json`: every exported policy (and with `baselines` ProMP, GMM-GMR and the nearest
              demonstration, pipeline.sim.baselines) in closed loop by each protocol (planned, online) in each
              condition: decided, free, changed (pipeline.sim.pick_loop).

A failed or interrupted run leaves the folder as empty as it found it.
"""

from __future__ import annotations

from concurrent.futures import as_completed
from pathlib import Path

from cnep.pipeline.progress import progress_bar
from cnep.pipeline.run.stage import open_policy
from cnep.pipeline.sim.baselines import BASELINES, baseline_policy
from cnep.pipeline.sim.config import PickPlaceConfig
from cnep.pipeline.sim.generate import generate_pick_demonstrations
from cnep.pipeline.sim.pick_loop import evaluate_pick_policy
from cnep.pipeline.sim.stage import by_model, run_in_new_folder, run_stages
from cnep.pipeline.sim.summary import format_pick_table
from cnep.pipeline.workers import single_thread_processes
from cnep.runtime.conditioning import ConditioningPolicy
from cnep.sim import require_extra
from cnep.sim.tasks.pick_place import scene as P

POLICY_THREADS = 1  # intra-op threads of the policy's graphs: one episode steps them one frame at a time


def run_pick_place(config: PickPlaceConfig) -> dict:
    """Run every stage into `config.out` (module docstring); returns the summary (also OUT/summary.json)."""
    require_extra()
    return run_in_new_folder(Path(config.out), "cnep sim pick-place", lambda out: _run_stages(config, out))


def _run_stages(config: PickPlaceConfig, out: Path) -> dict:
    """The six stages in order, each timed; returns the summary."""
    made, results, shared = run_stages(
        config,
        out,
        lambda recorded: generate_pick_demonstrations(recorded, config.demonstrations, config.seed, config.quiet),
        lambda policies: _closed_loop(config, out, policies),
    )
    return {
        "task": "pick-place",
        **shared,
        "demonstrations": {
            "n": len(made.folders),
            "places": {name: made.sides.count(name) for name, _, _ in P.PLACES},
            "clean": made.successes,
        },
        "models": by_model(results),
        "table": format_pick_table(results),
        "seconds": shared.pop("seconds"),
    }


def _closed_loop(config: PickPlaceConfig, out: Path, policies: dict[str, Path]) -> dict[str, dict]:
    """Stage 6: every policy in closed loop by each protocol in each condition, two at a time in single-threaded
    processes, its first episodes recorded under OUT/episodes; label -> results. The baselines, fitted with the first
    training seed's CNEP's normaliser and feature graph, carry that seed in their label."""
    (out / "episodes").mkdir()
    jobs = {label: (path, None) for label, path in policies.items()}
    if config.baselines:
        first = config.train_seeds[0]
        jobs.update({f"{name}-seed{first}": (policies[f"CNEP-seed{first}"], name) for name in BASELINES})
    results: dict[str, dict] = {}
    with single_thread_processes(2) as pool:
        futures = {pool.submit(_evaluate, config, out, label, *job): label for label, job in jobs.items()}
        for future in progress_bar(as_completed(futures), total=len(futures), desc="closed loop", unit="policy",
                                   quiet=config.quiet):  # fmt: skip
            results[futures[future]] = future.result()
    return {label: results[label] for label in jobs}


def _evaluate(config: PickPlaceConfig, out: Path, label: str, path: Path, baseline: str | None) -> dict:
    """One policy's closed loop (in a worker): the exported policy `path`, or the baseline `baseline` fitted beside
    the exported CNEP `path`, its waypoints covering the task's episode (a plan for PLANNED, which `max_steps` cuts
    short or holds at its end; ONLINE acts on the first)."""
    if baseline is None:
        conditioning = ConditioningPolicy(window=config.window, anchors=config.anchors)
        policy = open_policy(path, threads=POLICY_THREADS, waypoints=P.MAX_STEPS, conditioning=conditioning)
    else:
        trajectories = sorted((out / "trajectories").glob("*.mcap"))
        policy = baseline_policy(baseline, path, trajectories, config.pca, waypoints=P.MAX_STEPS)
    return evaluate_pick_policy(
        policy, config.protocols, P.CONDITIONS, config.episodes, label=label, max_steps=config.max_steps,
        episode_seed=config.episode_seed, record=config.record, recordings=out / "episodes", quiet=True,
    )  # fmt: skip
