import dataclasses

import pytest
import torch

from cnep.models.batched import BatchedTrainer, FitRun, fit_many
from cnep.models.config import TrainConfig
from cnep.models.errors import ConfigError
from cnep.models.train import fit, prepare_fit
from tests.models.factories import feature_config, feature_trajectories, tiny_config, two_mode_trajectories

# Steps cross the gate's freeze (30% = step 12), validations every 10 steps; lr high enough that gradients
# exceed the clipping norm (3) on some steps and not on others, so each model's own clipping norm matters.
# Batch 16 and latent 16 keep every product above torch's small-bmm threshold (see models.batched).
SCHEDULE = TrainConfig(steps=40, warmup_steps=5, val_every=10, batch_size=16, lr=1e-2, grad_clip=3.0)


def _runs() -> list[FitRun]:
    """Four runs of one shape: other seeds, other data, other loss weights (an ablation) or assignments (whose
    schedules follow the step and whose gates learn at their own rate), one layout with queries."""
    config = dataclasses.replace(tiny_config(n_experts=3), encoder_widths=(16, 16))
    runs = []
    losses = [{}, {"assignment": "annealed"}, {"assignment": "bounded"}, {"a_batch": 0.0, "a_ind": 0.0}]
    for seed, loss in enumerate(losses):
        trajs, _ = two_mode_trajectories(n=12, T=30, seed=seed)
        wide = [torch.randn(30, 5, generator=torch.Generator().manual_seed(seed)).numpy() + t for t in trajs]
        runs.append(
            FitRun(wide[:10], dataclasses.replace(config, **loss), dataclasses.replace(SCHEDULE, seed=seed), wide[10:])
        )
    return runs


@pytest.mark.slow
def test_each_batched_model_is_bit_identical_to_training_it_alone():
    runs = _runs()
    together = fit_many(runs)
    for run, (model, history) in zip(runs, together):
        alone, alone_history = fit(run.trajectories, run.config, run.train_config, run.val_trajectories, progress=False)
        for name, value in alone.state_dict().items():
            assert torch.equal(model.state_dict()[name], value), name
        assert history == alone_history  # losses, validation errors, gate usage: every recorded float
    assert len({float(m.state_dict()["gate.weight"].abs().sum()) for m, _ in together}) == 4  # four different models


def test_gradients_were_clipped_in_the_identity_test():
    """The identity test must exercise per-model clipping: some step's gradient norm exceeds grad_clip."""
    run = _runs()[0]
    trainer, _ = prepare_fit(run.trajectories, run.config, run.train_config, run.val_trajectories)
    norms = []
    original = torch.nn.utils.clip_grad_norm_

    def spy(params, max_norm, *args, **kwargs):
        norm = original(params, max_norm, *args, **kwargs)
        norms.append(float(norm))
        return norm

    torch.nn.utils.clip_grad_norm_ = spy
    try:
        trainer.run(progress=False)
    finally:
        torch.nn.utils.clip_grad_norm_ = original
    assert max(norms) > SCHEDULE.grad_clip > min(norms)


@pytest.mark.slow
def test_early_stopping_stops_each_model_as_alone():
    """A model that stops leaves the stack; the others go on with their Adam state, still bit-identical."""
    # on the paper's random contexts, where these runs' validation errors part: one stops while others train on
    stopping = {"patience": 1, "steps": 80, "online_contexts": 0.0}
    runs = [dataclasses.replace(r, train_config=dataclasses.replace(r.train_config, **stopping)) for r in _runs()]
    together = fit_many(runs)
    assert len({history[-1]["step"] for _, history in together}) > 1  # one stopped while others trained on
    for run, (model, history) in zip(runs, together):
        alone, alone_history = fit(run.trajectories, run.config, run.train_config, run.val_trajectories, progress=False)
        assert history == alone_history
        assert all(torch.equal(model.state_dict()[k], v) for k, v in alone.state_dict().items())


def test_models_of_different_shapes_or_schedules_are_not_batched_together():
    runs = _runs()[:2]
    other_shape = dataclasses.replace(runs[1], config=dataclasses.replace(runs[1].config, n_experts=2))
    trainers = [
        prepare_fit(r.trajectories, r.config, r.train_config, r.val_trajectories)[0] for r in (runs[0], other_shape)
    ]
    with pytest.raises(ConfigError, match="one network shape"):
        BatchedTrainer(trainers)
    other_steps = dataclasses.replace(runs[1], train_config=dataclasses.replace(runs[1].train_config, steps=30))
    results = fit_many([runs[0], other_steps])  # fit_many trains them apart
    assert [h[-1]["step"] for _, h in results] == [40, 30]


def test_models_reading_feature_components_train_together_each_with_its_own_projection_as_alone():
    config = feature_config(components=3)
    schedule = dataclasses.replace(SCHEDULE, steps=20, val_every=10)
    runs = [
        FitRun(feature_trajectories(n=8, seed=seed), config, dataclasses.replace(schedule, seed=seed))
        for seed in (0, 1)
    ]
    together = fit_many(runs)
    for run, (model, history) in zip(runs, together):
        alone, alone_history = fit(run.trajectories, run.config, run.train_config, progress=False)
        assert history == alone_history
        assert all(torch.equal(model.state_dict()[k], v) for k, v in alone.state_dict().items())
    first, second = (model.feature_projection for model, _ in together)
    assert not torch.allclose(first, second)  # each fitted on its own data
