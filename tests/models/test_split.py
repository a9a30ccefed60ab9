import dataclasses
import math

import pytest
import torch

import cnep.models.split
from cnep.models.batched import fit_many
from cnep.models.sampler import TrajectoryStack
from cnep.models.split import SPLIT_CHECKS, expert_part, owners, split_if_idle, split_steps
from cnep.models.train import build_model, fit, make_optimizer
from tests.models.factories import tiny_config, two_mode_trajectories
from tests.models.test_batched import _runs


def _model_with_adam(n_experts: int = 4):
    """A tiny CNEP, its training stack (12 demonstrations) and an Adam that has taken one step (moments set)."""
    trajs, _ = two_mode_trajectories(n=12, T=30, seed=0)
    wide = [torch.randn(30, 5, generator=torch.Generator().manual_seed(1)).numpy() + t for t in trajs]
    model = build_model(tiny_config(n_experts=n_experts), wide, seed=0)
    optimizer = make_optimizer([(list(model.parameters()), 1.0)], 1e-3)
    sum(p.sum() for p in model.parameters()).backward()
    optimizer.step()
    return model, TrajectoryStack(wide, model), optimizer


def _state(model, optimizer):
    params = dict(model.named_parameters())
    return params, {name: optimizer.state[p] for name, p in params.items()}


def test_an_idle_expert_takes_a_noisy_copy_of_the_busy_one_and_its_share_of_the_gate():
    model, stack, optimizer = _model_with_adam()
    with torch.no_grad():  # every demonstration's gate decided for expert 2
        model.gate.weight.zero_()
        model.gate.bias.copy_(torch.tensor([0.0, 0.0, 5.0, 0.0]))
    before = {name: p.detach().clone() for name, p in model.named_parameters()}
    obs, mask = stack.context(torch.arange(len(stack)))
    logits_before = model.gate(model.encode(obs, mask)).detach()
    params, state = _state(model, optimizer)

    idle, busy, counts = split_if_idle(model, stack, params, state, seed=0, step=7)

    assert busy == 2 and idle == 0 and counts == [0, 0, 12, 0]  # the first of the idle ones
    for name, p in model.named_parameters():
        src, dst = expert_part(name, p, busy, 4), expert_part(name, p, idle, 4)
        if name.startswith("experts."):
            assert torch.allclose(p[dst], before[name][src], atol=0.05) and not torch.equal(p[dst], before[name][src])
            assert torch.equal(p[src], before[name][src])  # the busy expert keeps its weights
            for moment in ("exp_avg", "exp_avg_sq"):
                assert torch.equal(state[name][moment][dst], state[name][moment][src])
        others = [e for e in range(4) if e not in (idle, busy)]
        for e in others if name.startswith(("experts.", "gate.")) else []:
            assert torch.equal(p[expert_part(name, p, e, 4)], before[name][expert_part(name, p, e, 4)])
        if name.startswith("encoder."):
            assert torch.equal(p, before[name])
    logits = model.gate(model.encode(obs, mask)).detach()
    assert torch.allclose(logits[:, idle], logits[:, busy])  # the pair shares what the busy expert had
    assert torch.allclose(logits[:, [idle, busy]].logsumexp(-1), logits_before[:, busy])
    assert torch.allclose(model.gate.bias[busy], torch.tensor(5.0 - math.log(2.0)))


def test_no_split_where_the_gate_is_undecided_or_no_expert_is_both_idle_and_busy(monkeypatch):
    model, stack, optimizer = _model_with_adam(n_experts=2)
    params, state = _state(model, optimizer)
    with torch.no_grad():
        model.gate.weight.zero_()
        model.gate.bias.zero_()  # uniform: decided for no expert
    assert owners(model, stack).tolist() == [0, 0]
    before = {name: p.detach().clone() for name, p in model.named_parameters()}
    assert split_if_idle(model, stack, params, state, seed=0, step=0) is None
    # 12 demonstrations, an equal share 6: idle below 3, busy above 9
    for counts, splits in (([4, 8], False), ([3, 9], False), ([2, 9], False), ([2, 10], True)):
        monkeypatch.setattr(cnep.models.split, "owners", lambda model, stack, c=counts: torch.tensor(c))
        assert (split_if_idle(model, stack, params, state, seed=0, step=0) is not None) == splits, counts
    assert all(
        torch.equal(p[expert_part(name, p, 1, 2)], before[name][expert_part(name, p, 1, 2)])
        for name, p in params.items()
        if name.startswith("experts.")
    )


def test_the_checks_fall_between_the_gates_unfreezing_and_the_balancings_fade():
    assert split_steps(4000, 1200, 0.6) == {int(f * 4000) for f in SPLIT_CHECKS}
    assert split_steps(4000, 1700, 0.5) == {1800}  # from after the freeze, before the fade
    assert split_steps(4000, 1200, 0.3) == frozenset()


@pytest.mark.slow
def test_a_split_in_a_stack_matches_the_same_split_alone(monkeypatch):
    """Splits at every check (owners forced to one busy expert) leave each batched model bit-identical to its run
    alone, Adam moments and noise included."""
    monkeypatch.setattr(cnep.models.split, "owners", lambda model, stack: torch.tensor([len(stack), 0, 0]))
    schedule = dataclasses.replace(_runs()[0].train_config, gate_freeze_fraction=0.3)
    runs = [
        dataclasses.replace(r, train_config=dataclasses.replace(schedule, seed=r.train_config.seed)) for r in _runs()
    ]
    runs = [r for r in runs if r.config.assignment in ("annealed", "bounded")]
    calls = []
    original = cnep.models.split.split

    def spy(*args):
        calls.append(args[2:4])
        return original(*args)

    monkeypatch.setattr(cnep.models.split, "split", spy)
    together = fit_many(runs)
    assert calls and all(c == (1, 0) for c in calls)
    for run, (model, history) in zip(runs, together):
        alone, alone_history = fit(run.trajectories, run.config, run.train_config, run.val_trajectories, progress=False)
        for name, value in alone.state_dict().items():
            assert torch.equal(model.state_dict()[name], value), name
        assert history == alone_history


def test_a_copy_of_one_unit_wide_layers_stays_finite():
    trajs, _ = two_mode_trajectories(n=4, T=10, seed=0)
    wide = [torch.randn(10, 5, generator=torch.Generator().manual_seed(1)).numpy() + t for t in trajs]
    model = build_model(dataclasses.replace(tiny_config(n_experts=2), expert_widths=(1, 1)), wide, seed=0)
    params = dict(model.named_parameters())
    cnep.models.split.split(params, {}, 1, 0, torch.Generator().manual_seed(0))
    assert all(torch.isfinite(p).all() for p in model.parameters())
    assert torch.equal(model.experts.first_b[1:2], model.experts.first_b[0:1])  # copied without noise
