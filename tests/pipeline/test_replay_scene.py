"""On-the-fly adaptation: when the scene changes mid-episode, the replay's gate moves to another expert.

A 2-expert CNEP is trained (a few hundred steps) on 1288-d trajectories of two synthetic scenes whose
feature columns differ (scene 0 lights up the first half of the features, scene 1 the second half) and
whose motions differ (the arm bends up or down). A recording that switches scene halfway is then
replayed through the checkpoint with online conditioning.
"""

import numpy as np
import pytest
import torch

from cnep.models import CNEPConfig, ColumnRoles, TrainConfig, fit, save_checkpoint
from cnep.pipeline.replay.decisions import read_decisions
from cnep.pipeline.replay.stage import replay
from cnep.recordings import Episode, Trajectory, write_trajectory
from cnep.recordings.constants import FEATURE_DIM, STEP_DIM

T = 60


def scene_rows(scene: int, rng: np.random.Generator) -> np.ndarray:
    """(T, 1288): scene-specific features, the arm bending up (scene 0) or down (scene 1), gripper by scene."""
    t = np.linspace(0, 1, T)
    data = np.zeros((T, STEP_DIM), np.float32)
    half = FEATURE_DIM // 2
    data[:, :FEATURE_DIM] = 0.2 * rng.random(FEATURE_DIM) + 0.05 * rng.standard_normal((T, FEATURE_DIM))
    data[:, scene * half : (scene + 1) * half] += 1.0
    sign = 1.0 if scene == 0 else -1.0
    data[:, 1280] = t
    data[:, 1281] = sign * 0.3 * np.sin(np.pi * t) + 0.02 * rng.standard_normal()
    data[:, 1282] = 0.5
    data[:, 1286] = 1.0  # identity quaternion (xyzw)
    data[:, 1287] = 0.5 + 0.5 * sign
    return data


def as_trajectory(data: np.ndarray, name: str) -> Trajectory:
    return Trajectory(
        episode=Episode(episode_id=name, fps=10.0),
        timestamps_ns=np.arange(len(data), dtype=np.int64) * 100_000_000,
        data=data,
        extractor={"architecture": "synthetic", "weights": "none"},
    )


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    demos = [scene_rows(i % 2, rng) for i in range(24)]
    columns = ColumnRoles(width=STEP_DIM, observed=((0, STEP_DIM),), predicted=((1280, STEP_DIM),))
    config = CNEPConfig(
        columns=columns, n_experts=2, encoder_widths=(32, 32), expert_widths=(32, 32), time_frequencies=2
    )
    train = TrainConfig(
        steps=300, batch_size=32, warmup_steps=100, gate_freeze_fraction=0.3, val_every=100, seed=0, lr=3e-3
    )
    model, _ = fit(demos, config, train, progress=False)
    return save_checkpoint(
        model,
        tmp_path_factory.mktemp("scene") / "ckpt",  # the features' extractor, as training records
        {"extractor": {"architecture": "synthetic", "weights": "none"}},
    )


@pytest.mark.slow
def test_the_gate_moves_to_another_expert_when_the_scene_changes(tmp_path, checkpoint, monkeypatch):
    monkeypatch.setenv("CI", "1")
    monkeypatch.setenv("HOME", str(tmp_path))
    rng = np.random.default_rng(1)
    a, b = scene_rows(0, rng), scene_rows(1, rng)
    switching = np.concatenate([a[: T // 2], b[T // 2 :]])
    paths = [
        write_trajectory(tmp_path / f"{name}.mcap", as_trajectory(data, name))
        for name, data in (("scene0", a), ("scene1", b), ("switch", switching))
    ]
    replay(checkpoint, paths, tmp_path / "scene.rrd", connect=None, quiet=True)
    pure0, pure1, switch = read_decisions(tmp_path / "scene.rrd")["recordings"]

    e0, e1 = pure0["majority_expert"], pure1["majority_expert"]
    assert e0 != e1, "the two scenes should be taken by different experts"
    assert min(pure0["share"][e0], pure1["share"][e1]) > 0.9

    experts = np.array(switch["experts"])
    assert (experts[: T // 2] == e0).mean() > 0.9  # scene 0 first ...
    assert (experts[-T // 4 :] == e1).all()  # ... then scene 1 once the window holds only scene-1 steps
    moves = [s for s in switch["switches"] if (s["from"], s["to"]) == (e0, e1)]
    assert moves and T // 2 <= moves[-1]["step"] <= T // 2 + 10  # within the conditioning window of the change
    gate = np.array(switch["gates"])
    assert gate[T // 2 - 1, e0] > 0.5 and gate[-1, e1] > 0.5
