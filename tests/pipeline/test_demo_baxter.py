"""The Baxter example on a tiny synthetic two-demonstration set with a box (never the authors' files)."""

from pathlib import Path

import numpy as np
import pytest

from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate.baxter import (
    BOX_X,
    BOX_Y,
    MODELS,
    BaxterConfig,
    format_table,
    in_box,
    load_paths,
    nearest_demo_distance,
    run_baxter,
    score_starts,
    train_models,
    xy_path,
)
from cnep.recordings import Demonstration, Episode

HEADER = "Time,p_x,p_y,p_z,q_x,q_y,q_z,q_w,gripper_position\n"
BOX_CENTRE = np.array([(BOX_X[0] + BOX_X[1]) / 2, (BOX_Y[0] + BOX_Y[1]) / 2])


def _write_csv(path: Path, xy: np.ndarray) -> None:
    rows = [f"{10 * k},{x},{y},-0.13,0.0,1.0,0.0,0.0,5.8" for k, (x, y) in enumerate(xy)]
    path.write_text(HEADER + "\n".join(rows) + "\n")


def _around(side: float, start_x: float, n: int = 60) -> np.ndarray:
    """A path from below the box to above it, bulging to the left (side < 0) or right of the box: (n, 2)."""
    s = np.linspace(0, 1, n)
    x = start_x + side * 0.2 * np.sin(np.pi * s)
    y = -0.48 + 0.37 * s
    return np.stack([x, y], axis=1)


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture
def data(tmp_path) -> Path:
    folder = tmp_path / "first"
    (folder / "start_end").mkdir(parents=True)
    _write_csv(folder / "start_end" / "demo_a.csv", _around(-1.0, 0.76))
    _write_csv(folder / "start_end" / "demo_b.csv", _around(+1.0, 0.95))
    _write_csv(folder / "0.csv", _around(0.0, 0.78, 40))
    _write_csv(folder / "1.csv", _around(0.0, 0.93, 40))
    return folder


def test_geometry_helpers():
    assert in_box(np.array([BOX_CENTRE, [0.5, -0.3], [0.8, -0.1]])).tolist() == [True, False, False]
    demos = np.stack([np.zeros((5, 2)), np.ones((5, 2))])
    assert nearest_demo_distance(np.full((5, 2), 0.9), demos) == pytest.approx(np.hypot(0.1, 0.1))
    t = np.array([0, 1, 3], dtype=np.int64) * 1_000_000_000
    pose = np.zeros((3, 7))
    pose[:, 0], pose[:, 6] = [0.0, 1.0, 3.0], 1.0
    demo = Demonstration(Episode("d", 1.0), t, pose, np.zeros(3))
    np.testing.assert_allclose(xy_path(demo, 4)[:, 0], [0, 1, 2, 3])  # even in time, not in samples


@pytest.mark.slow
def test_example_reports_every_start_point(data, tmp_path):
    config = BaxterConfig(data=data, work=tmp_path / "work", steps=10, samples=30, quiet=True)
    demos, tests = load_paths(config)
    assert (tmp_path / "work" / "demos" / "demo_a.mcap").is_file()  # went through the ingest stage
    models = train_models(demos, config)
    assert MODELS == (
        "CNMP",
        "CNEP (paper)",
        "CNEP-MoE (paper)",
        "CNEP (mixture)",
        "CNEP-MoE (mixture)",
        "CNEP (annealed)",
        "CNEP-MoE (annealed)",
        "CNEP (bounded)",
        "CNEP-MoE (bounded)",
    )
    for goal in (False, True):
        results = score_starts(models, demos, tests, goal)
        assert [r.name for r in results] == ["0", "1"]
        for r, x0 in zip(results, (0.78, 0.93)):
            np.testing.assert_allclose(r.start, [x0, -0.48])
            assert list(r.paths) == list(MODELS) and set(r.chosen_expert) == {
                "CNEP (paper)",
                "CNEP (mixture)",
                "CNEP (annealed)",
                "CNEP (bounded)",
            }
            for name in MODELS:
                path, executed = r.paths[name], r.executed[name]
                assert path.shape == executed.shape == (30, 2) and np.isfinite(path).all()
                assert r.enters_box[name] == bool(in_box(path).any())
                assert r.executed_enters_box[name] == bool(in_box(executed).any())
                assert 0 <= r.distance[name] < 0.3
                # the PID executes from the real start and passes through every conditioning point
                np.testing.assert_allclose(executed[0], r.start, atol=1e-9)
                assert r.executed_miss[name] < (1e-3 if goal else 1e-9)
        table = format_table(results)
        assert table.count("\n") == 4 and "| 0 | (0.780, -0.480) |" in table
        assert "| box entries, generated / PID |" in table
    again = run_baxter(config)  # the whole example, seeded: the same paths
    first = score_starts(models, demos, tests, goal=False)
    for name in MODELS:
        np.testing.assert_array_equal(again[0].paths[name], first[0].paths[name])


def test_missing_demonstrations_folder_is_a_clear_error(tmp_path):
    (tmp_path / "0.csv").write_text(HEADER)
    with pytest.raises(PipelineError, match="start_end"):
        run_baxter(BaxterConfig(data=tmp_path, quiet=True))
