"""The authors' Baxter obstacle-avoidance recordings: does a model commit to one side of the box or cut through it?

Data (read in place, never copied): a folder like the paper's `data/baxter/first/` holding
`start_end/*.csv` (two demonstrations that pass a box on opposite sides) and test recordings
`0.csv`, `1.csv`, ... whose first samples are new start points. Steps:

1. ingest every CSV with the ingest stage (Baxter CSV format, motion-only demonstration files in a
   work folder);
2. take the end-effector's (p_x, p_y) (m), resample each demonstration to `samples` steps evenly in
   time (t = k / (samples - 1)); the model's normaliser standardises the columns;
3. train a 2-expert CNEP and a CNMP (1 expert, widened to about the same number of parameters) with
   `models.fit`, seeded; with only two demonstrations both serve for training and validation;
4. condition each model on each test recording's first sample at t = 0 (and, with `goal=True`, also
   on its last sample at t = 1) and generate the path at the `samples` times (winner-take-all);
5. per start point and model: the distance to the nearest demonstration (mean over time of the
   distance between generated and demonstrated points at equal t, minimum over the demonstrations)
   and whether the path enters the box.
"""

from __future__ import annotations

import logging
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from models import CNEPConfig, Layout, TrainConfig, fit, matched_cnmp
from pipeline.errors import PipelineError
from pipeline.ingest.stage import IngestConfig, ingest
from recordings import Demonstration, read_demonstration

log = logging.getLogger(__name__)

DEMO_FOLDER = "start_end"
BOX_X = (0.71, 0.95)  # m, the obstacle's extent in the paper's set-up
BOX_Y = (-0.36, -0.24)
SAMPLES = 200
LAYOUT_XY = Layout(width=2, observed=((0, 2),), query=(), predicted=((0, 2),))


@dataclass(frozen=True)
class BaxterConfig:
    """data: the folder with `start_end/*.csv` and the test CSVs; work: where ingested files go (a temporary
    folder when None); steps / seed: training; goal: also condition on each test recording's last sample."""

    data: Path
    work: Path | None = None
    steps: int = 4000
    seed: int = 0
    samples: int = SAMPLES
    goal: bool = False
    quiet: bool = False


@dataclass(frozen=True)
class StartResult:
    """One test start point: where it is, and per model (`CNEP`, `CNMP`) the generated path's scores."""

    name: str
    start: np.ndarray  # (2,) m
    distance: dict[str, float]  # model -> mean distance to the nearest demonstration (m)
    enters_box: dict[str, bool]  # model -> any generated point inside the box
    chosen_expert: int  # the CNEP's winner-take-all expert
    paths: dict[str, np.ndarray]  # model -> (samples, 2)


def xy_path(demo: Demonstration, samples: int) -> np.ndarray:
    """(p_x, p_y) of a demonstration resampled evenly in time: (samples, 2) in m."""
    t = (demo.timestamps_ns - demo.timestamps_ns[0]) / max(1, demo.timestamps_ns[-1] - demo.timestamps_ns[0])
    grid = np.linspace(0.0, 1.0, samples)
    return np.stack([np.interp(grid, t, demo.pose[:, i]) for i in range(2)], axis=1)


def in_box(path: np.ndarray) -> np.ndarray:
    """(N,) bool: which points of a (N, 2) path lie inside the box."""
    return ((path[:, 0] >= BOX_X[0]) & (path[:, 0] <= BOX_X[1]) & (path[:, 1] >= BOX_Y[0]) & (path[:, 1] <= BOX_Y[1]))


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
        raise PipelineError(f"{data}: expected the demonstrations in {DEMO_FOLDER}/*.csv and test recordings *.csv "
                            f"beside it (the paper's data/baxter/first/ folder); give that folder")
    demos = _ingest_paths(demo_dir, work / "demos", config.quiet)
    if len(demos) < 2:
        raise PipelineError(f"{demo_dir}: found {len(demos)} demonstration(s); the example needs at least 2")
    return demos, [p for test in tests for p in _ingest_paths(test, work / "tests", config.quiet)]


def train_models(demos: np.ndarray, config: BaxterConfig) -> dict:
    """A 2-expert CNEP and a parameter-matched CNMP on (N, T, 2) paths; both seeded."""
    train = TrainConfig(steps=config.steps, warmup_steps=config.steps // 10, val_every=max(1, config.steps // 20),
                        seed=config.seed)
    trajectories = list(demos)
    models = {}
    cnep = CNEPConfig(layout=LAYOUT_XY, n_experts=2)
    for name, cfg in (("CNEP", cnep), ("CNMP", matched_cnmp(cnep))):
        log.info("training %s on %d demonstrations for %d steps", name, len(demos), config.steps)
        models[name], _ = fit(trajectories, cfg, train, val_trajectories=trajectories, progress=not config.quiet)
    return models


def run_baxter(config: BaxterConfig) -> list[StartResult]:
    """The whole example (see the module docstring); one result per test recording, in file order."""
    import torch

    torch.manual_seed(config.seed)
    with tempfile.TemporaryDirectory(prefix="cnep-baxter-") as tmp:
        work = Path(config.work) if config.work is not None else Path(tmp)
        demo_files, test_files = load_recordings(config, work)
        demos = np.stack([xy_path(read_demonstration(p), config.samples) for p in demo_files])  # (N, T, 2)
        tests = [(p, read_demonstration(p)) for p in test_files]
    models = train_models(demos, config)
    grid = np.linspace(0.0, 1.0, config.samples)
    results = []
    for path, demo in tests:
        start, goal = demo.pose[0, :2], demo.pose[-1, :2]
        obs_t, obs_y = (np.array([0.0, 1.0]), np.stack([start, goal])) if config.goal else (np.zeros(1), start[None])
        predictions = {name: model.generate(obs_t, obs_y, grid) for name, model in models.items()}
        paths = {name: p.mean for name, p in predictions.items()}
        results.append(StartResult(
            name=path.stem, start=start,
            distance={name: nearest_demo_distance(p, demos) for name, p in paths.items()},
            enters_box={name: bool(in_box(p).any()) for name, p in paths.items()},
            chosen_expert=predictions["CNEP"].expert, paths=paths))
    return results


def format_table(results: list[StartResult]) -> str:
    """A markdown table: per start point, nearest-demonstration distance (cm) and box entry of CNEP and CNMP."""
    lines = ["| start | (x, y) m | CNEP expert | CNEP dist. to nearest demo (cm) | CNEP enters box | "
             "CNMP dist. to nearest demo (cm) | CNMP enters box |",
             "|---|---|---|---|---|---|---|"]
    for r in results:
        lines.append(f"| {r.name} | ({r.start[0]:.3f}, {r.start[1]:.3f}) | {r.chosen_expert} | "
                     f"{100 * r.distance['CNEP']:.1f} | {'yes' if r.enters_box['CNEP'] else 'no'} | "
                     f"{100 * r.distance['CNMP']:.1f} | {'yes' if r.enters_box['CNMP'] else 'no'} |")
    return "\n".join(lines)
