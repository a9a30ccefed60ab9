import dataclasses

import numpy as np
import pytest
import torch

from cnep.models.assignments import ASSIGNMENTS
from cnep.models.cnep import CNEP
from cnep.models.config import CNEPConfig, ColumnRoles, ConditioningPolicy, TrainConfig
from cnep.models.errors import ConfigError
from cnep.models.sampler import TrajectoryStack
from cnep.models.schedule import scheduled
from cnep.models.split import SPLIT_CHECKS
from cnep.models.synthetic import make_set
from cnep.models.train import (
    LEARNED_RATIO,
    Trainer,
    build_model,
    finish_fit,
    fit,
    lr_factor,
    prepare_fit,
    split_validation,
)
from tests.models.factories import tiny_config, two_mode_trajectories

SMALL = {"encoder_widths": (32, 32), "expert_widths": (32, 32), "time_frequencies": 4}
QUICK = TrainConfig(steps=60, warmup_steps=10, val_every=20, batch_size=8)


@pytest.mark.slow
def test_same_seed_same_model_different_seed_different_model():
    trajs, _ = two_mode_trajectories()
    a, _ = fit(trajs, CNEPConfig(**SMALL), QUICK, progress=False)
    b, _ = fit(trajs, CNEPConfig(**SMALL), QUICK, progress=False)
    c, _ = fit(trajs, CNEPConfig(**SMALL), TrainConfig(**{**QUICK.to_dict(), "seed": 1}), progress=False)
    for k, v in a.state_dict().items():
        torch.testing.assert_close(b.state_dict()[k], v, rtol=0, atol=0)
    assert any(not torch.equal(c.state_dict()[k], v) for k, v in a.state_dict().items())


def test_validation_split_is_by_whole_trajectory_and_disjoint():
    trajs = [np.full((5, 1), i, dtype=np.float32) for i in range(10)]
    train, val = split_validation(trajs, 0.2, seed=0)
    ids = lambda xs: {int(x[0, 0]) for x in xs}  # noqa: E731
    assert len(val) == 2 and len(train) == 8 and not ids(train) & ids(val)
    with pytest.raises(ConfigError, match="at least 2"):
        split_validation(trajs[:1], 0.2, seed=0)


@pytest.mark.slow
def test_gate_stays_uniform_while_frozen_and_moves_after():
    trajs, _ = two_mode_trajectories()
    cfg = TrainConfig(steps=200, warmup_steps=10, gate_freeze_fraction=0.5, val_every=100, batch_size=16)
    model = build_model(CNEPConfig(**SMALL), trajs, seed=0)
    trainer = Trainer(model, TrajectoryStack(trajs, model), TrajectoryStack(trajs[:4], model), cfg)
    trainer.run(progress=False, until=100)
    assert torch.count_nonzero(model.gate.weight) == 0 and torch.count_nonzero(model.gate.bias) == 0
    trainer.run(progress=False)
    assert torch.count_nonzero(model.gate.weight) > 0


@pytest.mark.parametrize("scale", [1.0, 0.25])
def test_gate_learns_at_its_share_of_the_learning_rate(scale):
    """Adam's first step moves every parameter with a gradient by about lr: the gate by lr * gate_lr_scale."""
    trajs, _ = two_mode_trajectories()
    cfg = TrainConfig(steps=10, warmup_steps=0, gate_freeze_fraction=0.0, gate_lr_scale=scale, lr=1e-3, batch_size=16)
    model = build_model(CNEPConfig(**SMALL), trajs, seed=0)
    before = {name: p.detach().clone() for name, p in model.named_parameters()}
    Trainer(model, TrajectoryStack(trajs, model), TrajectoryStack(trajs[:4], model), cfg).train_step()
    moved = {name: float((p.detach() - before[name]).abs().max()) for name, p in model.named_parameters()}
    assert moved["gate.weight"] == pytest.approx(1e-3 * scale, rel=1e-3)
    assert max(v for name, v in moved.items() if not name.startswith("gate.")) == pytest.approx(1e-3, rel=1e-3)


@pytest.mark.parametrize("assignment", ["paper", "bounded"])
def test_the_gates_learning_rate_defaults_to_its_assignments(assignment):
    trajs, _ = two_mode_trajectories()
    cfg = TrainConfig(steps=10, warmup_steps=0, gate_freeze_fraction=0.0, lr=1e-3, batch_size=16)
    assert cfg.gate_lr_scale is None and TrainConfig(gate_lr_scale=0.5).for_assignment(assignment).gate_lr_scale == 0.5
    model = build_model(CNEPConfig(**SMALL, assignment=assignment), trajs, seed=0)
    before = model.gate.weight.detach().clone()
    trainer = Trainer(model, TrajectoryStack(trajs, model), TrajectoryStack(trajs[:4], model), cfg)
    trainer.train_step()
    assert trainer.cfg.gate_lr_scale == ASSIGNMENTS[assignment].gate_lr_scale
    assert float((model.gate.weight.detach() - before).abs().max()) == pytest.approx(
        1e-3 * ASSIGNMENTS[assignment].gate_lr_scale, rel=1e-3
    )


def test_no_model_from_before_the_posterior_settles_is_kept():
    """ "bounded" balances its posterior until 0.8 of the steps: the best model comes from a validation at or after
    it."""
    trajs, _ = two_mode_trajectories()
    cfg = dataclasses.replace(QUICK, val_every=5)
    trainer, _ = prepare_fit(trajs, CNEPConfig(**SMALL, assignment="bounded"), cfg)
    trainer.run(progress=False)
    settled = [h["val_error"] for h in trainer.history if h["step"] >= 0.8 * cfg.steps]
    assert trainer.best_step >= 0.8 * cfg.steps and trainer.best_error == min(settled)
    assert min(h["val_error"] for h in trainer.history) < trainer.best_error  # an earlier model was better and not kept


def test_learning_rate_warms_up_then_decays():
    cfg = TrainConfig(steps=1000, warmup_steps=100)
    assert lr_factor(0, cfg) == pytest.approx(0.01)
    assert lr_factor(99, cfg) == pytest.approx(1.0)
    assert lr_factor(999, cfg) == pytest.approx(0.05, abs=1e-3)
    assert lr_factor(500, cfg) < lr_factor(200, cfg)


def test_the_defaults_train_the_schedule_that_commits_the_demo_s_and_the_commitment_table_s():
    """The schedule of the demo's and the commitment table's data (docs/results.md, from 51 to 307 training
    demonstrations), which `fit`, `cnep train` and `cnep demo` leave to it: the learning rate still warming up when
    the gate unfreezes and at the first split check."""
    from cnep.pipeline.demo.config import FULL

    assert FULL.train_steps is FULL.warmup_steps is FULL.val_every is None  # the schedule's
    for demonstrations in (51, 160, 307):
        cfg = scheduled(TrainConfig(), demonstrations)
        assert (cfg.steps, cfg.warmup_steps, cfg.val_every) == (4000, 2000, 500)
    assert lr_factor(int(cfg.gate_freeze_fraction * cfg.steps), cfg) < lr_factor(int(SPLIT_CHECKS[0] * cfg.steps), cfg)
    assert lr_factor(int(SPLIT_CHECKS[0] * cfg.steps), cfg) < 1.0 == lr_factor(cfg.warmup_steps, cfg)


def test_trajectories_of_the_wrong_width_are_refused():
    with pytest.raises(ConfigError, match=r"\(T, 1\)"):
        fit([np.zeros((10, 2))] * 4, CNEPConfig(**SMALL), QUICK, progress=False)


@pytest.mark.slow
def test_two_modes_end_on_different_experts():
    trajs, modes = two_mode_trajectories(n=24, T=60)
    cfg = TrainConfig(steps=600, warmup_steps=120, val_every=200, batch_size=32)
    model, history = fit(trajs, CNEPConfig(n_experts=2, **SMALL), cfg, progress=False)
    t = np.linspace(0, 1, 60)
    chosen = []
    for traj in trajs:
        steps = np.array([0, 15, 45])  # the modes differ away from the shared start
        chosen.append(model.generate(t[steps], traj[steps], t).expert)
    chosen = np.array(chosen)
    assert len(set(chosen[modes == 0])) == 1 and len(set(chosen[modes == 1])) == 1
    assert chosen[modes == 0][0] != chosen[modes == 1][0]
    assert history[-1]["val_error"] < 0.05


def test_fit_with_two_trajectories_trains_on_both_and_says_so(caplog):
    trajs, _ = two_mode_trajectories(n=2)
    with caplog.at_level("WARNING", logger="cnep.models.train"):
        model, history = fit(trajs, CNEPConfig(**SMALL), QUICK, progress=False)
    assert history[-1]["n_train"] == 2 and history[-1]["validation"] == "training set"
    assert "only 2 trajectories" in caplog.text
    # both demonstrations shaped the normaliser: it is the statistics of the two together
    both = np.concatenate(trajs)
    np.testing.assert_allclose(model.normaliser.loc.numpy(), both.mean(axis=0), rtol=1e-5, atol=1e-6)


def test_fit_holds_out_a_reported_fifth_from_ten_trajectories_on(caplog):
    trajs, _ = two_mode_trajectories(n=10)
    with caplog.at_level("INFO", logger="cnep.models.train"):
        _, history = fit(trajs, CNEPConfig(**SMALL), QUICK, progress=False)
    assert (history[0]["n_train"], history[0]["n_val"], history[0]["validation"]) == (8, 2, "held out")
    assert "validating on 2 of the 10 trajectories" in caplog.text


@pytest.mark.parametrize("threads", [1, pytest.param(2, marks=pytest.mark.slow), None])  # two threads: slow when busy
def test_fit_trains_on_the_configs_threads_and_restores_the_count(monkeypatch, threads):
    trajs, _ = two_mode_trajectories(n=4)
    seen, step = [], Trainer.train_step
    monkeypatch.setattr(Trainer, "train_step", lambda self: seen.append(torch.get_num_threads()) or step(self))
    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        fit(trajs, CNEPConfig(**SMALL), dataclasses.replace(QUICK, steps=4, threads=threads), progress=False)
        assert set(seen) == {3 if threads is None else threads} and torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)
    assert TrainConfig().threads == 1  # the stages' count (models.threads.SMALL_MODEL_THREADS)


def test_first_steps_contexts_reach_the_training_and_validation_batches():
    trajs, _ = two_mode_trajectories()
    cfg = dataclasses.replace(QUICK, first_steps_fraction=1.0, first_steps_max=1)
    trainer, _ = prepare_fit(trajs, CNEPConfig(**SMALL), cfg)
    for batch in [trainer.next_batch(), *trainer.val_batches]:  # every context: the first step alone, at t = 0
        assert (batch.obs_mask.sum(1) == 1).all() and (batch.obs[:, 0, 0] == 0).all()
    plain, _ = prepare_fit(trajs, CNEPConfig(**SMALL), QUICK)
    assert (plain.next_batch().obs_mask.sum(1) > 1).any()


def test_online_contexts_take_the_shape_of_the_conditioning_the_model_is_trained_for():
    trajs, _ = two_mode_trajectories()
    cfg = dataclasses.replace(QUICK, online_contexts=1.0)
    trainer, _ = prepare_fit(trajs, CNEPConfig(**SMALL), cfg, conditioning=ConditioningPolicy(window=3, anchors=0))
    T = len(trajs[0])
    assert all(len(t) == T for t in trajs)
    for batch in [trainer.next_batch(), *trainer.val_batches]:  # the latest 3 steps at most, in a row
        count = batch.obs_mask.sum(1)
        times = batch.obs[..., 0]
        latest = times.masked_fill(~batch.obs_mask, -1.0).amax(1)
        earliest = times.masked_fill(~batch.obs_mask, 2.0).amin(1)
        assert (count <= 3).all() and batch.obs.shape[1] == QUICK.n_max
        torch.testing.assert_close((latest - earliest) * (T - 1), (count - 1).to(times.dtype))
        assert (batch.query[..., 0] > latest[:, None])[batch.target_mask].all()


def test_the_demonstrations_nll_reads_the_latent_of_the_training_steps_forward_pass(monkeypatch):
    import cnep.models.train as train

    batches, same = [], []
    next_batch, demonstration_nll = train.Trainer.next_batch, train.demonstration_nll

    def spy_batch(self):
        batches.append(next_batch(self))
        return batches[-1]

    def spy_nll(model, r, demonstration):  # r against the batch's contexts encoded afresh, before the step
        with torch.no_grad():
            same.append(torch.equal(r, model.encode(batches[-1].obs, batches[-1].obs_mask)))
        return demonstration_nll(model, r, demonstration)

    monkeypatch.setattr(train.Trainer, "next_batch", spy_batch)
    monkeypatch.setattr(train, "demonstration_nll", spy_nll)
    trajs, _ = two_mode_trajectories(n=4, T=10, seed=0)
    config = CNEPConfig(n_experts=2, assignment="bounded", **SMALL)
    fit(trajs, config, TrainConfig(steps=3, warmup_steps=1, val_every=3), progress=False)
    assert same == [True, True, True]


def test_the_observed_only_spans_are_the_context_values_and_encoder_inputs_of_columns_never_predicted():
    def spans(**columns) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
        model = CNEP(CNEPConfig(columns=ColumnRoles(width=6, **columns), time_frequencies=2))
        return model.observed_only_columns(), model.observed_only_inputs()

    # a context is t, then the observed columns; the encoder's inputs are t's 1 + 2 x 2 time features, then those
    assert spans(observed=((0, 4),), predicted=((2, 6),)) == ([(1, 3)], [(5, 7)])  # columns 0, 1: a camera's
    assert spans(observed=((0, 2), (4, 6)), predicted=((1, 5),)) == ([(1, 2), (4, 5)], [(5, 6), (8, 9)])  # 0 and 5
    assert spans(observed=((0, 6),), predicted=((0, 6),)) == ([], [])  # a model that predicts all it observes


def test_observed_only_dropout_zeroes_or_scales_those_encoder_inputs_and_leaves_the_batch_as_it_was():
    trajs = [np.random.default_rng(i).standard_normal((20, 5)).astype(np.float32) for i in range(6)]
    columns = ColumnRoles(width=5, observed=((0, 2), (3, 5)), query=((2, 3),), predicted=((3, 5),))
    config = CNEPConfig(columns=columns, n_experts=2, **{**SMALL, "time_frequencies": 0})  # t, 0-1 (observed only), 3-4

    def batch(share: float):
        cfg = TrainConfig(steps=10, warmup_steps=2, val_every=10, batch_size=64, observed_only_dropout=share)
        trainer, _ = prepare_fit(trajs, config, cfg)
        return trainer.model, trainer.next_batch()

    (model, plain), (_, dropped) = batch(0.0), batch(0.25)
    assert plain.keep is None and dropped.keep.shape == (*dropped.obs.shape[:-1], 2)
    assert all(torch.equal(getattr(dropped, f), getattr(plain, f)) for f in ("obs", "obs_mask", "query", "target"))
    seen, full = model.encoder_inputs(dropped.obs, dropped.keep), model.encoder_inputs(plain.obs)
    mask = plain.obs_mask
    assert torch.equal(seen[..., [0, 3, 4]], full[..., [0, 3, 4]])  # t and the predicted columns
    ratio = seen[..., 1:3][mask] / full[..., 1:3][mask]
    assert torch.allclose(ratio[ratio != 0], torch.tensor(1 / 0.75))  # the kept values, scaled up
    assert 0.2 < (ratio == 0).float().mean() < 0.3  # about a quarter zeroed, value by value
    with pytest.raises(ConfigError, match=r"observed_only_dropout must be in \[0, 1\)"):
        TrainConfig(observed_only_dropout=1.0)


def test_observed_only_decay_shrinks_those_weights_by_the_steps_learning_rate_and_nothing_else():
    trajs = [np.random.default_rng(i).standard_normal((20, 5)).astype(np.float32) for i in range(6)]
    config = tiny_config(n_experts=2)  # observes columns 0-1, predicts 3-4
    lr = {}

    def one_step(decay: float) -> dict[str, torch.Tensor]:
        cfg = TrainConfig(steps=10, warmup_steps=2, val_every=10, batch_size=4, observed_only_decay=decay)
        trainer, _ = prepare_fit(trajs, config, cfg)
        trainer.train_step()
        lr[decay] = trainer.optimizer.param_groups[0]["lr"]
        return {k: v.clone() for k, v in trainer.model.state_dict().items()}

    plain, decayed = one_step(0.0), one_step(3.0)
    assert lr[0.0] == lr[3.0] == 5e-4  # the warm-up's first step
    assert CNEP(config).observed_only_inputs() == [(5, 7)]  # after t's 1 + 2 x 2 time features: columns 0-1
    expected = plain["encoder.0.weight"].clone()
    expected[:, 5:7] *= 1.0 - 5e-4 * 3.0
    assert torch.equal(decayed["encoder.0.weight"], expected)
    assert not torch.equal(decayed["encoder.0.weight"], plain["encoder.0.weight"])
    assert all(torch.equal(decayed[k], v) for k, v in plain.items() if k != "encoder.0.weight")


def test_an_observed_only_decay_that_would_flip_weights_is_refused_only_where_it_acts():
    trajs = [np.random.default_rng(i).standard_normal((20, 5)).astype(np.float32) for i in range(6)]
    cfg = TrainConfig(steps=10, warmup_steps=2, val_every=10, lr=0.5, observed_only_decay=3.0)
    with pytest.raises(ConfigError, match=r"observed_only_decay x lr must be below 1 .* 3.0 x 0.5"):
        prepare_fit(trajs, tiny_config(n_experts=2), cfg)
    prepare_fit(two_mode_trajectories(n=8, T=20)[0], CNEPConfig(n_experts=2, **SMALL), cfg)  # no such weights


def test_observed_only_decay_and_dropout_leave_a_model_that_predicts_all_it_observes_as_it_was():
    trajs, _ = two_mode_trajectories(n=8, T=20, seed=0)
    config = CNEPConfig(n_experts=2, **SMALL)  # observes and predicts the one column
    off = dataclasses.replace(QUICK, observed_only_decay=0.0, observed_only_dropout=0.0)
    plain, _ = fit(trajs, config, off, progress=False)
    decayed, _ = fit(trajs, config, dataclasses.replace(QUICK, observed_only_decay=3.0), progress=False)
    assert all(torch.equal(decayed.state_dict()[k], v) for k, v in plain.state_dict().items())


@pytest.mark.slow
def test_a_run_no_better_than_predicting_the_training_mean_warns_naming_the_cause_and_the_numbers(caplog):
    data = make_set("unimodal", seed=0)
    columns = ColumnRoles(width=1, observed=((0, 1),), query=(), predicted=((0, 1),))
    config = CNEPConfig(columns=columns, n_experts=2, encoder_widths=(16, 16), expert_widths=(16, 16))
    for lr, learns in ((0.01, True), (1.0, False)):
        caplog.clear()
        training = TrainConfig(steps=150, batch_size=8, warmup_steps=10, val_every=50, patience=None, seed=0, lr=lr)
        trainer, _ = prepare_fit(list(data.train[:16]), config, training, list(data.val))
        trainer.run(progress=False)
        with caplog.at_level("WARNING"):
            finish_fit(trainer, {})
        assert (trainer.best_error < LEARNED_RATIO * trainer.mean_error) == learns
        assert ("learned nothing" in caplog.text) != learns, caplog.text
    numbers = f"best validation error ({trainer.best_error:.4g}) is no better than predicting the training mean "
    assert f"{numbers}({trainer.mean_error:.4g}, normalised units" in caplog.text
    assert "likely cause: the learning rate, 1000 times the default (lr 1; the default is 0.001)" in caplog.text
