"""models.candidates: the best validation of each part of training, kept as a copy, and a Trainer's candidates."""

import torch

from cnep.models import CNEPConfig, TrainConfig, Trainer, build_model
from cnep.models.candidates import Candidates
from cnep.models.sampler import TrajectoryStack
from tests.models.factories import two_mode_trajectories


def test_each_part_keeps_its_lowest_error_as_a_copy_and_an_equal_one_keeps_the_earlier():
    candidates = Candidates(n=3, first=30, last=119)  # parts of 30 steps: 30-59, 60-89, 90-119
    assert [candidates.part(step) for step in (30, 59, 60, 89, 90, 119, 120)] == [0, 0, 1, 1, 2, 2, 2]
    state = {"w": torch.zeros(2)}
    for step, error in ((40, 0.5), (50, 0.3), (60, 0.4), (70, 0.4), (100, 0.2)):
        state["w"] += 1
        candidates.offer(step, error, state)
    assert [(kept.step, kept.error) for kept in candidates.in_order()] == [(50, 0.3), (60, 0.4), (100, 0.2)]
    assert [float(kept.state["w"][0]) for kept in candidates.in_order()] == [2.0, 3.0, 5.0]  # copies, not views
    again = Candidates(n=3, first=30, last=119)
    again.load_state_dict(candidates.state_dict())
    assert [(k.step, k.error) for k in again.in_order()] == [(k.step, k.error) for k in candidates.in_order()]


def test_a_trainer_keeps_candidates_and_its_best_weights_are_one_of_them():
    trajectories, _ = two_mode_trajectories(n=8, T=20)
    config = CNEPConfig(n_experts=2, encoder_widths=(16,), expert_widths=(16,), time_frequencies=2)
    model = build_model(config, trajectories, seed=0)
    cfg = TrainConfig(steps=40, batch_size=8, warmup_steps=4, val_every=5, patience=None, seed=0)
    trainer = Trainer(
        model,
        TrajectoryStack(trajectories[:6], model),
        TrajectoryStack(trajectories[6:], model),
        cfg,
        keep_candidates=3,
    )
    trainer.run(progress=False)
    kept = trainer.candidates.in_order()
    assert 1 <= len(kept) <= 3 and all(k.step >= trainer.keep_from for k in kept)
    for k in kept:  # each the lowest validation error of its part
        part = [h for h in trainer.history if h["step"] >= trainer.keep_from and trainer.candidates.part(h["step"])
                == trainer.candidates.part(k.step)]  # fmt: skip
        assert k.error == min(h["val_error"] for h in part)
    best = next(k for k in kept if k.step == trainer.best_step)
    assert all(torch.equal(best.state[name], trainer.best_state[name]) for name in trainer.best_state)
