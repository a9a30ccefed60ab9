"""A policy in closed loop: `evaluate_policy` runs it for `episodes` episodes per protocol in the simulator, writes
the first `record` of each as Rerun recordings and returns the rates and rows (pipeline.sim.summary).

Episode i is reset with seed `episode_seed + i`: every policy meets the same starts (and cue sides), and the same
seed gives the same episode bit for bit. The demonstrations' starts come from other seeds
(pipeline.sim.generate.DEMO_SEED_OFFSET), so every episode is unseen.
"""

from __future__ import annotations

import importlib.util
import logging
from pathlib import Path

from cnep.models.config import ConditioningOverrides
from cnep.pipeline.progress import progress_bar
from cnep.pipeline.run.config import own_conditioning
from cnep.pipeline.run.stage import open_policy
from cnep.pipeline.sim.config import LoopSettings
from cnep.pipeline.sim.figure import draw_episode
from cnep.pipeline.sim.rerun_log import write_episode
from cnep.pipeline.sim.summary import episode_row, rates
from cnep.runtime import Policy
from cnep.sim import ObstacleEnv, run_episode
from cnep.sim import scene as S

log = logging.getLogger(__name__)

POLICY_THREADS = 1  # intra-op threads of the policy's graphs: one episode steps them one frame at a time


def evaluate_policy(
    policy_path: Path,
    settings: LoopSettings,
    *,
    label: str,
    extractor: Path | None = None,
    recordings: Path | None = None,
    figure: Path | None = None,
    quiet: bool = False,
) -> dict[str, dict]:
    """Protocol -> rates (pipeline.sim.summary.rates) of the policy in `policy_path` (exported or checkpoint);
    recordings: the folder for `<label>-<protocol>-seed<N>.rrd` (None: none written); figure: the PNG of the last
    protocol's first episode (pipeline.sim.figure; None, or matplotlib missing: none drawn)."""
    policy = _policy(policy_path, extractor, settings.conditioning)
    env = ObstacleEnv(cue=settings.cue, max_steps=settings.max_steps)
    results = {}
    try:
        for protocol in settings.protocols:
            rows = []
            bar = progress_bar(range(settings.episodes), desc=f"{label} {protocol}", unit="episode", quiet=quiet)
            for i in bar:
                seed = settings.episode_seed + i
                record = recordings is not None and i < settings.record
                drawn = figure is not None and i == 0 and protocol == settings.protocols[-1] and _plots()
                ep = run_episode(env, policy, seed, protocol, record_frames=record or drawn)
                name = f"{label}-{protocol}-seed{seed}"
                if record:
                    write_episode(recordings / f"{name}.rrd", name, ep, policy.n_experts)
                if drawn:
                    draw_episode(ep, name, figure)
                rows.append(episode_row(ep))
            results[protocol] = rates(rows)
    finally:
        env.close()
    return results


def _policy(path: Path, extractor: Path | None, given: ConditioningOverrides) -> Policy:
    """The policy in `path`, its waypoints covering the task's episode (a plan: a limit of steps cuts it short or
    holds its end, and never rescales it), its conditioning its own but for the settings `given`."""
    conditioning = given.applied(own_conditioning(path)) if given.given() else None
    return open_policy(
        path, extractor=extractor, threads=POLICY_THREADS, waypoints=S.MAX_STEPS, conditioning=conditioning
    )


def _plots() -> bool:
    """Whether matplotlib (the `plots` extra) is installed; a warning when it is not."""
    if importlib.util.find_spec("matplotlib") is None:
        log.warning("no episode figure: matplotlib is missing; pip install 'cnep-pipeline[plots]'")
        return False
    return True
