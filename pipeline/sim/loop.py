"""A policy in closed loop on a task: `evaluate_policy` runs it for `episodes` episodes per protocol (and per condition
where the task has conditions) in the simulator, writes the first `record` of each as Rerun recordings and returns
the rates and rows (the task's scoring: Task.row, Task.rates).

Episode i is reset with seed `episode_seed + i`: every policy meets the same scenes, and the same seed gives the same
episode bit for bit. The demonstrations come from other seeds (sim.task.demonstration_seed), so every episode is
unseen.
"""

from __future__ import annotations

import importlib.util
import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TypeVar

from cnep.models.config import ConditioningOverrides
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.run.config import own_conditioning
from cnep.pipeline.run.stage import open_policy
from cnep.pipeline.sim.config import VARIANTS
from cnep.pipeline.sim.figure import draw_episode
from cnep.pipeline.sim.rerun_log import write_episode
from cnep.runtime import Policy
from cnep.sim.episode import run_episode
from cnep.sim.task import Task

log = logging.getLogger(__name__)

POLICY_THREADS = 1  # intra-op threads of the policy's graphs: one episode steps them one frame at a time
S = TypeVar("S")


def for_task(settings: S, task: Task) -> S:
    """`settings` (a config of pipeline.sim.config) with the task's episode length where they leave max_steps to the
    task; PipelineError for a variant the task does not have."""
    for name in VARIANTS:
        if getattr(settings, name, False) and name not in task.variants:
            raise PipelineError(f"--{name} is a variant of another task; the {task.name} task has none")
    return settings if settings.max_steps is not None else replace(settings, max_steps=task.max_steps)


def episodes_of(task: Task, settings) -> int:
    """The episodes one policy runs: per protocol, and per condition where the task has conditions."""
    return settings.episodes * len(settings.protocols) * max(1, len(task.conditions))


def evaluate_policy(
    policy: Policy,
    task: Task,
    settings,
    *,
    label: str,
    recordings: Path | None = None,
    figure: Path | None = None,
    progress: Callable[[int], None] | None = None,
) -> dict[str, dict]:
    """Protocol -> rates (Task.rates; where the task has conditions, protocol -> condition -> rates) of `policy` (a
    runtime.Policy, or a baseline behind its interface, its waypoints covering the task's episode for PLANNED).
    settings: the loop's (pipeline.sim.config: episodes, max_steps, episode_seed, protocols, record and the task's
    variants); recordings: the folder for `<label>-<protocol>[-<condition>]-seed<N>.rrd` (None: none written);
    figure: the PNG of the first episode of the last protocol and condition (pipeline.sim.figure; None, or matplotlib
    missing: none drawn); progress: called with the number of episodes done after each."""
    variants = {name: getattr(settings, name) for name in task.variants}
    conditions = task.conditions or (None,)
    results: dict[str, dict] = {protocol: {} for protocol in settings.protocols}
    done = 0
    for condition in conditions:
        env = task.make_env(condition, settings.max_steps, **variants)
        try:
            for protocol in settings.protocols:
                rows = []
                for i in range(settings.episodes):
                    seed = settings.episode_seed + i
                    record = recordings is not None and i < settings.record
                    last = (protocol, condition) == (settings.protocols[-1], conditions[-1])
                    drawn = figure is not None and i == 0 and last and _plots()
                    ep = run_episode(env, policy, seed, protocol, record_frames=record or drawn)
                    name = "-".join([label, protocol, *([condition] if condition else []), f"seed{seed}"])
                    if record:
                        write_episode(recordings / f"{name}.rrd", name, ep, policy.n_experts, task.drawing(ep))
                    if drawn:
                        draw_episode(ep, name, figure, task.drawing(ep))
                    rows.append(task.row(ep))
                    done += 1
                    if progress is not None:
                        progress(done)
                if condition is None:
                    results[protocol] = task.rates(rows)
                else:
                    results[protocol][condition] = task.rates(rows)
        finally:
            env.close()
    return results


def open_task_policy(
    path: Path, task: Task, given: ConditioningOverrides | None = None, extractor: Path | None = None
) -> Policy:
    """The policy in `path` (exported or checkpoint), its waypoints covering the task's episode (a plan: a limit of
    steps cuts it short or holds its end, and never rescales it), its conditioning its own (the checkpoint's
    config.json, the manifest's) but for the settings `given`."""
    conditioning = given.applied(own_conditioning(path)) if given is not None and given.given() else None
    return open_policy(
        path, extractor=extractor, threads=POLICY_THREADS, waypoints=task.max_steps, conditioning=conditioning
    )


def _plots() -> bool:
    """Whether matplotlib (the `plots` extra) is installed; a warning when it is not."""
    if importlib.util.find_spec("matplotlib") is None:
        log.warning("no episode figure: matplotlib is missing; pip install 'cnep-pipeline[plots]'")
        return False
    return True
