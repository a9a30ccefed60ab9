"""The authors' Baxter obstacle-avoidance recordings: does a model commit to one side of the box or cut through it?

Data (read in place, never copied): a folder like the paper's `data/baxter/first/` holding
`start_end/*.csv` (two demonstrations that pass a box on opposite sides) and test recordings
`0.csv`, `1.csv`, ... whose first samples are new start points. Steps:

1. ingest every CSV with the ingest stage (Baxter CSV format, motion-only demonstration files in a
   work folder);
2. take the end-effector's (p_x, p_y) (m), resample each demonstration to `samples` steps evenly in
   time (t = k / (samples - 1)); the model's normaliser standardises the columns;
3. train a 2-expert CNEP per assignment of the loss (`models.CNEPConfig.assignment`: the paper's
   gate-weighted NLL, the mixture likelihood, the annealed posterior balanced to equal or to bounded
   shares) and a CNMP (1 expert, widened to about the same number of parameters) with `models.fit`,
   seeded; with only two demonstrations both serve for training and validation;
4. condition each model on each test recording's first sample at t = 0 (and, with `goal=True`, also
   on its last sample at t = 1) and generate the path at the `samples` times: each CNEP winner-take-all
   (the paper's inference) and as the gate-weighted mixture of its experts (CNEP-MoE);
5. execute each generated path with the paper's PID controller (`models.pid_track`) from the real start:
   the reference is the generated path bent through the conditioning points, so the executed path
   passes through them (the paper's use of the controller);
6. per start point and model: the distance to the nearest demonstration (mean over time of the
   distance between generated and demonstrated points at equal t, minimum over the demonstrations),
   whether the generated path and whether the executed path enter the box, and how far the executed
   path passes from the conditioning points.
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.models import CNEPConfig, ColumnRoles, TrainConfig, fit, matched_cnmp, pid_track
from cnep.models.assignments import ASSIGNMENTS
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.ingest.stage import IngestConfig, ingest
from cnep.pipeline.inputs import coerce_paths
from cnep.recordings import Demonstration, read_demonstration

log = logging.getLogger(__name__)

DEMO_FOLDER = "start_end"
BOX_X = (0.71, 0.95)  # m, the obstacle's extent in the paper's set-up
BOX_Y = (-0.36, -0.24)
SAMPLES = 200
COLUMNS_XY = ColumnRoles(width=2, observed=((0, 2),), query=(), predicted=((0, 2),))


@dataclass(frozen=True)
class BaxterConfig:
    """data: the folder with `start_end/*.csv` and the test CSVs; work: where ingested files go (a temporary
    folder when None); steps / seed / nll_beta: training (steps None: the training schedule's, models.schedule;
    nll_beta: the loss's beta-NLL power, `cnep train`'s default); goal: also condition on each test recording's last
    sample."""

    data: Path
    work: Path | None = None
    steps: int | None = None
    seed: int = 0
    nll_beta: float = TrainConfig().nll_beta
    samples: int = SAMPLES
    goal: bool = False
    quiet: bool = False

    def __post_init__(self) -> None:
        coerce_paths(self)
        TrainConfig(steps=self.steps, seed=self.seed, nll_beta=self.nll_beta)  # ConfigError before the ingest


@dataclass(frozen=True)
class StartResult:
    """One test start point: where it is, and per model (`MODELS`) the generated and the executed path's scores."""

    name: str
    start: np.ndarray  # (2,) m
    distance: dict[str, float]  # model -> mean distance of the generated path to the nearest demonstration (m)
    enters_box: dict[str, bool]  # model -> any generated point inside the box
    chosen_expert: dict[str, int]  # CNEP model -> its winner-take-all expert
    paths: dict[str, np.ndarray]  # model -> generated (samples, 2)
    executed: dict[str, np.ndarray]  # model -> executed by the PID controller from the start (samples, 2)
    executed_enters_box: dict[str, bool]  # model -> any executed point inside the box
    executed_miss: dict[str, float]  # model -> largest distance of the executed path from a conditioning point (m)


def cnep_name(assignment: str, mixture: bool = False) -> str:
    """The result name of the CNEP trained with `assignment`, winner-take-all or as a mixture of experts."""
    return f"CNEP{'-MoE' if mixture else ''} ({assignment})"


# Every model of a result, in table order: the CNMP, then per assignment the CNEP and its mixture of experts.
MODELS = ("CNMP", *(cnep_name(a, moe) for a in ASSIGNMENTS for moe in (False, True)))


def xy_path(demo: Demonstration, samples: int) -> np.ndarray:
    """(p_x, p_y) of a demonstration resampled evenly in time: (samples, 2) in m."""
    t = (demo.timestamps_ns - demo.timestamps_ns[0]) / max(1, demo.timestamps_ns[-1] - demo.timestamps_ns[0])
    grid = np.linspace(0.0, 1.0, samples)
    return np.stack([np.interp(grid, t, demo.pose[:, i]) for i in range(2)], axis=1)


def in_box(path: np.ndarray) -> np.ndarray:
    """(N,) bool: which points of a (N, 2) path lie inside the box."""
    return (path[:, 0] >= BOX_X[0]) & (path[:, 0] <= BOX_X[1]) & (path[:, 1] >= BOX_Y[0]) & (path[:, 1] <= BOX_Y[1])


def nearest_demo_distance(path: np.ndarray, demos: np.ndarray) -> float:
    """Mean distance (m) between `path` (T, 2) and the nearest of `demos` (N, T, 2), point by point at equal t."""
    return float(np.linalg.norm(demos - path[None], axis=-1).mean(axis=1).min())


def _ingest_paths(src: Path, out: Path, quiet: bool) -> list[Path]:
    # the example's own work folder: a second run re-ingests (replaces) what the first one wrote there
    return [item.output for item in ingest(IngestConfig(src=src, out=out, force=True, quiet=quiet))]


def load_recordings(config: BaxterConfig, work: Path) -> tuple[list[Path], list[Path]]:
    """Ingest the demonstrations and the test recordings into `work`; returns (demo files, test files)."""
    data = Path(config.data)
    demo_dir = data / DEMO_FOLDER
    tests = sorted((p for p in data.glob("*.csv")), key=lambda p: (len(p.stem), p.stem))
    if not demo_dir.is_dir() or not tests:
        raise PipelineError(
            f"{data}: expected the demonstrations in {DEMO_FOLDER}/*.csv and test recordings *.csv "
            f"beside it (the paper's data/baxter/first/ folder); give that folder"
        )
    demos = _ingest_paths(demo_dir, work / "demos", config.quiet)
    if len(demos) < 2:
        raise PipelineError(f"{demo_dir}: found {len(demos)} demonstration(s); the example needs at least 2")
    return demos, [p for test in tests for p in _ingest_paths(test, work / "tests", config.quiet)]


def train_models(demos: np.ndarray, config: BaxterConfig) -> dict:
    """A 2-expert CNEP per assignment ("CNEP (paper)", "CNEP (mixture)", "CNEP (annealed)", "CNEP (bounded)") and
    a parameter-matched "CNMP" on (N, T, 2) paths; all seeded."""
    # the rest the training schedule's (models.schedule)
    train = TrainConfig(steps=config.steps, seed=config.seed, nll_beta=config.nll_beta)
    trajectories = list(demos)
    models = {}
    configs = {"CNMP": matched_cnmp(CNEPConfig(columns=COLUMNS_XY, n_experts=2, assignment="paper"))}
    configs.update({cnep_name(a): CNEPConfig(columns=COLUMNS_XY, n_experts=2, assignment=a) for a in ASSIGNMENTS})
    for name, cfg in configs.items():
        log.info("training %s on %d demonstrations", name, len(demos))
        models[name], _ = fit(trajectories, cfg, train, val_trajectories=trajectories, progress=not config.quiet)
    return models


def load_paths(config: BaxterConfig) -> tuple[np.ndarray, list[tuple[str, Demonstration]]]:
    """The demonstrations' (N, samples, 2) paths and the test recordings (name, demonstration), in file order."""
    with tempfile.TemporaryDirectory(prefix="cnep-baxter-") as tmp:
        work = Path(config.work) if config.work is not None else Path(tmp)
        demo_files, test_files = load_recordings(config, work)
        demos = np.stack([xy_path(read_demonstration(p), config.samples) for p in demo_files])  # (N, T, 2)
        return demos, [(p.stem, read_demonstration(p)) for p in test_files]


def score_starts(
    models: dict, demos: np.ndarray, tests: list[tuple[str, Demonstration]], goal: bool
) -> list[StartResult]:
    """Condition `models` (from `train_models`) on each test's start (and goal), generate, execute, score."""
    samples = demos.shape[1]
    grid = np.linspace(0.0, 1.0, samples)
    results = []
    for name, demo in tests:
        start, end = demo.pose[0, :2], demo.pose[-1, :2]
        obs_t, obs_y = (np.array([0.0, 1.0]), np.stack([start, end])) if goal else (np.zeros(1), start[None])
        steps = np.rint(obs_t * (samples - 1)).astype(int)
        paths, experts = {}, {}
        for model_name, model in models.items():
            p = model.generate(obs_t, obs_y, grid)
            paths[model_name] = p.mean
            if model.n_experts > 1:
                experts[model_name] = p.expert
                paths[model_name.replace("CNEP", "CNEP-MoE")] = model.generate(obs_t, obs_y, grid, mixture=True).mean
        paths = {m: paths[m] for m in MODELS if m in paths}
        executed = {m: pid_track(p, steps, obs_y, start=start) for m, p in paths.items()}
        results.append(
            StartResult(
                name=name,
                start=start,
                distance={m: nearest_demo_distance(p, demos) for m, p in paths.items()},
                enters_box={m: bool(in_box(p).any()) for m, p in paths.items()},
                chosen_expert=experts,
                paths=paths,
                executed=executed,
                executed_enters_box={m: bool(in_box(x).any()) for m, x in executed.items()},
                executed_miss={m: float(np.linalg.norm(x[steps] - obs_y, axis=-1).max()) for m, x in executed.items()},
            )
        )
    return results


def run_baxter(config: BaxterConfig) -> list[StartResult]:
    """The whole example (see the module docstring); one result per test recording, in file order."""
    import torch

    torch.manual_seed(config.seed)
    demos, tests = load_paths(config)
    return score_starts(train_models(demos, config), demos, tests, config.goal)


def _yes(flag: bool) -> str:
    return "yes" if flag else "no"


def format_table(results: list[StartResult]) -> str:
    """A markdown table: per start point and model, the generated path's distance to the nearest demonstration
    (cm), whether the generated / the PID-executed path enters the box, and the CNEPs' chosen experts; then
    the box entries per model."""
    models = [m for m in MODELS if m in results[0].paths]
    lines = ["| start | (x, y) m | " + " | ".join(models) + " |", "|---" * (len(models) + 2) + "|"]
    for r in results:
        cells = []
        for m in models:
            expert = f"expert {r.chosen_expert[m]}, " if m in r.chosen_expert else ""
            cells.append(
                f"{expert}{100 * r.distance[m]:.1f} cm, {_yes(r.enters_box[m])} / {_yes(r.executed_enters_box[m])}"
            )
        lines.append(f"| {r.name} | ({r.start[0]:.3f}, {r.start[1]:.3f}) | " + " | ".join(cells) + " |")
    n = len(results)
    lines.append(
        "| box entries, generated / PID | | "
        + " | ".join(
            f"{sum(r.enters_box[m] for r in results)}/{n} / {sum(r.executed_enters_box[m] for r in results)}/{n}"
            for m in models
        )
        + " |"
    )
    return "\n".join(lines)
