"""The `scene` layout preset: observe the frames' features with the motion, query with time only."""

from pathlib import Path

import numpy as np
import pytest

from cnep.models import CNEPConfig, TrainConfig, load_checkpoint, read_checkpoint_config
from cnep.models.online import ConditioningPolicy
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.replay.conditioning import decide
from cnep.pipeline.train.checkpoint import load_trained
from cnep.pipeline.train.constants import PRESET_NAMES, SCENE
from cnep.pipeline.train.presets import resolve_preset
from cnep.pipeline.train.stage import TrainStageConfig, train
from cnep.recordings import read_trajectory, write_trajectory
from tests.recordings.factories import trajectory_factory

pytestmark = pytest.mark.usefixtures("one_thread")

EXAMPLE = Path("traj/demo-0.mcap")  # only named in errors


def test_scene_observes_everything_queries_nothing_predicts_the_motion():
    scene = resolve_preset(SCENE, 1288, EXAMPLE)
    assert SCENE in PRESET_NAMES
    assert scene.columns == ((0, 1288),) and scene.roles.width == 1288
    assert (scene.roles.observed, scene.roles.query, scene.roles.predicted) == (((0, 1288),), (), ((1280, 1288),))
    assert scene.roles.query_dim == 0 and scene.roles.out_dim == 8
    wine = resolve_preset("wine-glass", 1288, EXAMPLE)
    assert (wine.roles.observed, wine.roles.predicted) == (scene.roles.observed, scene.roles.predicted)
    assert scene.to_dict()["query"] == [] and scene.to_dict()["observed"][0] == "features"


def test_scene_refuses_motion_only_files():
    with pytest.raises(PipelineError, match=r"demo-0\.mcap.*features.*--layout motion"):
        resolve_preset(SCENE, 8, EXAMPLE)


def test_a_scene_checkpoint_generates_and_replays_online(tmp_path):
    (tmp_path / "traj").mkdir()
    paths = [
        write_trajectory(tmp_path / "traj" / f"demo-{k}.mcap", trajectory_factory(12 + 3 * k, seed=k)) for k in range(4)
    ]
    training = TrainConfig(steps=20, batch_size=8, warmup_steps=2, val_every=10, seed=1)
    out = train(
        TrainStageConfig(
            inputs=tuple(paths),
            out=tmp_path / "ckpt",
            layout=SCENE,
            model=CNEPConfig(n_experts=3, encoder_widths=(16, 16), expert_widths=(16, 16), time_frequencies=2),
            training=training,
            quiet=True,
        )
    )
    assert read_checkpoint_config(out)["layout"]["name"] == SCENE
    model = load_checkpoint(out)
    traj = read_trajectory(paths[1])
    prediction = model.generate(np.array([0.0]), traj.data[:1], np.linspace(0, 1, 5), None)
    assert prediction.mean.shape == (5, 8) and np.isfinite(prediction.mean).all()

    trained = load_trained(out)
    mapping, rows = trained.mapping, trained.rows(traj, paths[1])
    decisions = decide(model, rows, traj.timestamps_ns, ConditioningPolicy(), xyz=mapping.predicted_xyz(model))
    assert decisions.gates.shape == (traj.n_steps, 3)
    np.testing.assert_allclose(decisions.gates.sum(1), 1.0, atol=1e-5)
    assert decisions.predictions.shape[0] == traj.n_steps and np.isfinite(decisions.predictions).all()
    # at the last step the online set is the first step (anchor) + the latest `window` steps
    T, policy = traj.n_steps, ConditioningPolicy()
    kept = [0, *range(T - policy.window, T)]
    t = np.arange(T) / (T - 1)
    np.testing.assert_allclose(decisions.gates[-1], model.generate(t[kept], rows[kept], t[:1], None).gate, atol=1e-4)
