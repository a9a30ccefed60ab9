import dataclasses
import math

import pytest
import torch

from cnep.models.assignments import ANNEAL_FRACTION, ASSIGNMENTS
from cnep.models.config import CNEPConfig
from cnep.models.loss import (
    SINKHORN_ITERATIONS,
    annealed_posterior,
    annealed_sharpness,
    balanced,
    cnep_loss,
    entropy,
    expert_nll,
)


def test_expert_nll_against_a_hand_computation():
    mean = torch.tensor([[[[0.0], [1.0]], [[2.0], [2.0]]]])  # (B=1, d=2, M=2, dy=1)
    std = torch.tensor([[[[1.0], [2.0]], [[0.5], [0.5]]]])
    target = torch.tensor([[[0.0], [3.0]]])  # (1, 2, 1)
    mask = torch.tensor([[True, True]])

    def nll(y, mu, s):
        return 0.5 * ((y - mu) / s) ** 2 + math.log(s) + 0.5 * math.log(2 * math.pi)

    expected = [[(nll(0, 0, 1) + nll(3, 1, 2)) / 2, (nll(0, 2, 0.5) + nll(3, 2, 0.5)) / 2]]
    torch.testing.assert_close(expert_nll(mean, std, target, mask), torch.tensor(expected))
    # a masked target does not count
    only_first = expert_nll(mean, std, target, torch.tensor([[True, False]]))
    torch.testing.assert_close(only_first, torch.tensor([[nll(0, 0, 1), nll(0, 2, 0.5)]]))


def test_beta_nll_weights_each_value_by_its_variance_without_differentiating_the_weight():
    mean = torch.tensor([[[[0.0, 0.0]]]], requires_grad=True)  # (B=1, d=1, M=1, dy=2)
    std = torch.tensor([[[[0.1, 2.0]]]], requires_grad=True)  # one value predicted closely, one hard
    target = torch.tensor([[[1.0, 1.0]]])
    mask = torch.tensor([[True]])
    plain = expert_nll(mean, std, target, mask)
    (grad_plain,) = torch.autograd.grad(plain.sum(), mean)
    assert grad_plain[0, 0, 0, 0] / grad_plain[0, 0, 0, 1] == pytest.approx(400.0)  # the variances' ratio
    weighted = expert_nll(mean, std, target, mask, beta=1.0)
    torch.testing.assert_close(weighted, _nll_terms(std, 1.0))
    (grad_mean, grad_std) = torch.autograd.grad(weighted.sum(), (mean, std))
    torch.testing.assert_close(grad_mean, -(target - mean.detach()) / 2)  # beta 1: the squared error's gradient
    (grad_std_plain,) = torch.autograd.grad(expert_nll(mean, std, target, mask).sum(), std)
    torch.testing.assert_close(grad_std, grad_std_plain * std.detach() ** 2)  # the weight itself is not differentiated
    half = expert_nll(mean, std, target, mask, beta=0.5)
    (grad_half,) = torch.autograd.grad(half.sum(), mean)
    assert grad_half[0, 0, 0, 0] / grad_half[0, 0, 0, 1] == pytest.approx(20.0)  # the stds' ratio


def _nll_terms(std: torch.Tensor, beta: float) -> torch.Tensor:
    """The mean over the two values of test_beta_nll's NLL, each weighted by variance ** beta: (1, 1)."""
    s = std.detach()[0, 0, 0]  # (2,)
    nll = 0.5 / s**2 + s.log() + 0.5 * math.log(2 * math.pi)
    return (nll * s ** (2 * beta)).mean().reshape(1, 1)


def test_entropy_is_stable_at_zero_and_per_row():
    p = torch.tensor([[1.0, 0.0], [0.5, 0.5]], requires_grad=True)
    h = entropy(p)
    torch.testing.assert_close(h, torch.tensor([0.0, math.log(2)]))
    h.sum().backward()
    assert torch.isfinite(p.grad).all()


def test_total_loss_terms_and_signs_against_a_hand_computation():
    cfg = CNEPConfig(n_experts=2, a_rec=2.0, a_batch=3.0, a_ind=5.0, assignment="paper")
    mean = torch.zeros(2, 2, 1, 1)
    std = torch.ones(2, 2, 1, 1)
    target = torch.tensor([[[1.0]], [[0.0]]])  # (B=2, M=1, dy=1)
    gate = torch.tensor([[0.9, 0.1], [0.3, 0.7]])
    total, terms = cnep_loss(mean, std, gate, target, torch.ones(2, 1, dtype=torch.bool), cfg)

    c = 0.5 * math.log(2 * math.pi)
    L = [[0.5 + c, 0.5 + c], [c, c]]  # per sample, per expert
    rec = ((0.9 * L[0][0] + 0.1 * L[0][1]) / 2 + (0.3 * L[1][0] + 0.7 * L[1][1]) / 2) / 2
    H = lambda ps: -sum(p * math.log(p) for p in ps)  # noqa: E731
    batch = H([0.6, 0.4])
    ind = (H([0.9, 0.1]) + H([0.3, 0.7])) / 2
    assert math.isclose(terms["rec"], rec, rel_tol=1e-6)
    assert math.isclose(terms["batch_entropy"], batch, rel_tol=1e-6)
    assert math.isclose(terms["ind_entropy"], ind, rel_tol=1e-6)
    assert math.isclose(total.item(), 2 * rec - 3 * batch + 5 * ind, rel_tol=1e-6)


def test_batch_entropy_is_rewarded_and_individual_entropy_penalised():
    cfg = CNEPConfig(n_experts=2, a_rec=0.0, a_batch=1.0, a_ind=1.0)
    args = (torch.zeros(2, 2, 1, 1), torch.ones(2, 2, 1, 1), torch.zeros(2, 1, 1), torch.ones(2, 1, dtype=torch.bool))
    collapsed = torch.tensor([[1.0, 0.0], [1.0, 0.0]])  # confident, but one expert for all
    spread = torch.tensor([[1.0, 0.0], [0.0, 1.0]])  # confident, both experts used
    unsure = torch.tensor([[0.5, 0.5], [0.5, 0.5]])  # both used on average, no confidence
    loss = {
        name: cnep_loss(*args[:2], g, *args[2:], cfg)[0].item()
        for name, g in [("collapsed", collapsed), ("spread", spread), ("unsure", unsure)]
    }
    assert loss["spread"] < loss["collapsed"]
    assert loss["spread"] < loss["unsure"]


def _nll(y: float, mu: float, s: float) -> float:
    return 0.5 * ((y - mu) / s) ** 2 + math.log(s) + 0.5 * math.log(2 * math.pi)


def test_mixture_term_against_a_hand_computation():
    # sample 0: two targets (one masked out of three), dy = 1; sample 1: one target
    cfg = CNEPConfig(n_experts=2, a_rec=1.0, a_batch=0.0, a_ind=0.0, assignment="mixture")
    mean, std, target, mask, gate, _, _ = _two_sample_example()
    _, terms = cnep_loss(mean, std, gate, target, mask, cfg)

    S0 = [_nll(0, 0, 1) + _nll(3, 1, 2), _nll(0, 2, 0.5) + _nll(3, 2, 0.5)]  # summed NLL per expert
    S1 = [_nll(1, 0.5, 1), _nll(1, -1, 2)]
    rec0 = -math.log(0.8 * math.exp(-S0[0]) + 0.2 * math.exp(-S0[1])) / 2  # n_0 = 2 target values
    rec1 = -math.log(0.4 * math.exp(-S1[0]) + 0.6 * math.exp(-S1[1])) / 1
    assert math.isclose(terms["rec"], (rec0 + rec1) / 2 / 2, rel_tol=1e-6)  # mean over samples, then / d


def test_mixture_term_is_stable_when_every_expert_is_far_off():
    # exp(-S) underflows for every expert (S ~ 5e5): logsumexp keeps the term finite and exact
    cfg = CNEPConfig(n_experts=2, a_batch=0.0, a_ind=0.0, assignment="mixture")
    mean = torch.tensor([[[[0.0]], [[0.0]]]], requires_grad=True)  # (1, 2, 1, 1)
    std = torch.full((1, 2, 1, 1), 1e-3)
    gate = torch.tensor([[0.5, 0.5]], requires_grad=True)
    total, terms = cnep_loss(mean, std, gate, torch.ones(1, 1, 1), torch.ones(1, 1, dtype=torch.bool), cfg)
    assert math.isclose(terms["rec"], _nll(1, 0, 1e-3) / 2, rel_tol=1e-5)  # both experts equal: log 1 = 0
    total.backward()
    assert torch.isfinite(mean.grad).all() and torch.isfinite(gate.grad).all()


def test_mixture_sends_the_targets_to_the_expert_that_explains_them():
    # expert 0 fits the targets, expert 1 does not: the mixture trains (almost) only expert 0's mean,
    # where the paper's term trains each expert in proportion to the gate (0.5 / 0.5)
    mean = torch.tensor([[[[0.9], [1.1]], [[-1.0], [-1.0]]]], requires_grad=True)  # (1, 2, 2, 1)
    std, target = torch.full((1, 2, 2, 1), 0.2), torch.ones(1, 2, 1)
    gate, mask = torch.tensor([[0.5, 0.5]]), torch.ones(1, 2, dtype=torch.bool)
    grads = {}
    for assignment in ("paper", "mixture"):
        cfg = CNEPConfig(n_experts=2, a_rec=1.0, a_batch=0.0, a_ind=0.0, assignment=assignment)
        mean.grad = None
        cnep_loss(mean, std, gate, target, mask, cfg)[0].backward()
        grads[assignment] = mean.grad.abs().sum((0, 2, 3))  # (d,)
    assert grads["mixture"][1] < 1e-6 * grads["mixture"][0]
    torch.testing.assert_close(
        grads["paper"][1] / grads["paper"][0], torch.tensor(4.0 / 0.2), rtol=1e-5, atol=0
    )  # sum |y - mu|


@pytest.mark.parametrize(
    "assignment, progress", [("mixture", 1.0), ("annealed", 0.2), ("annealed", 1.0), ("bounded", 0.2)]
)
def test_each_assignment_equals_the_paper_term_with_one_expert_in_value_and_gradient(assignment, progress):
    # d = 1: -log(1 * exp(-S_i)) / n_i = S_i / n_i = L_i, and the paper's (1/1) sum_e p_ie L_ie = L_i.
    # The equality needs the mixture's sum over a sample's target values divided by their number n_i
    # (samples with different n_i: 3 and 1 targets, dy = 2) and the (1/d) of both terms (1 here);
    # "annealed" at progress 0.2 is still balancing its posterior, which one expert leaves at 1.
    g = torch.Generator().manual_seed(0)
    mean = torch.randn(2, 1, 3, 2, generator=g, requires_grad=True)
    std = (0.5 + torch.rand(2, 1, 3, 2, generator=g)).requires_grad_()
    target = torch.randn(2, 3, 2, generator=g)
    mask = torch.tensor([[True, True, True], [True, False, False]])
    gate = torch.ones(2, 1)
    out = {}
    for name in ("paper", assignment):
        cfg = CNEPConfig(n_experts=1, assignment=name)
        mean.grad = std.grad = None
        total, terms = cnep_loss(mean, std, gate, target, mask, cfg, progress)
        total.backward()
        out[name] = (total.detach(), mean.grad.clone(), std.grad.clone(), terms)
    for a, b in zip(out["paper"][:3], out[assignment][:3]):
        torch.testing.assert_close(a, b)
    assert out["paper"][3] == out[assignment][3]  # rec, both entropies (0 with one expert), total


def test_mixture_equals_the_paper_term_when_the_experts_agree():
    # with d > 1 the terms differ in general, but not when every expert predicts the same:
    # -log sum_e p_ie exp(-S_i) = S_i whatever the gate, and sum_e p_ie L_i = L_i
    mean = torch.randn(3, 1, 4, 1, generator=torch.Generator().manual_seed(1)).expand(3, 3, 4, 1)
    std, target = torch.ones(3, 3, 4, 1), torch.zeros(3, 4, 1)
    gate = torch.softmax(torch.randn(3, 3, generator=torch.Generator().manual_seed(2)), -1)
    mask = torch.ones(3, 4, dtype=torch.bool)
    recs = [
        cnep_loss(mean, std, gate, target, mask, CNEPConfig(n_experts=3, assignment=a))[1]["rec"]
        for a in ("paper", "mixture")
    ]
    assert math.isclose(recs[0], recs[1], rel_tol=1e-6)
    # and they differ as soon as the experts disagree
    apart = mean + torch.arange(3.0)[None, :, None, None]
    recs = [
        cnep_loss(apart, std, gate, target, mask, CNEPConfig(n_experts=3, assignment=a))[1]["rec"]
        for a in ("paper", "mixture")
    ]
    assert not math.isclose(recs[0], recs[1], rel_tol=1e-3)


def test_annealed_sharpness_rises_geometrically_from_one_to_the_number_of_values():
    values = torch.tensor([1.0, 16.0, 0.0])  # a sample without targets counts as one value
    torch.testing.assert_close(annealed_sharpness(values, 0.0), torch.tensor([1.0, 1.0, 1.0]))
    torch.testing.assert_close(annealed_sharpness(values, ANNEAL_FRACTION / 2), torch.tensor([1.0, 4.0, 1.0]))
    for progress in (ANNEAL_FRACTION, 1.0, 2.0):
        torch.testing.assert_close(annealed_sharpness(values, progress), torch.tensor([1.0, 16.0, 1.0]))


def _two_sample_example():
    # sample 0: two targets (one masked out of three), dy = 1; sample 1: one target
    mean = torch.tensor(
        [[[[0.0], [1.0], [9.0]], [[2.0], [2.0], [9.0]]], [[[0.5], [0.0], [0.0]], [[-1.0], [0.0], [0.0]]]]
    )  # (B=2, d=2, M=3, dy=1)
    std = torch.tensor([[[[1.0], [2.0], [1.0]], [[0.5], [0.5], [1.0]]], [[[1.0], [1.0], [1.0]], [[2.0], [1.0], [1.0]]]])
    target = torch.tensor([[[0.0], [3.0], [5.0]], [[1.0], [0.0], [0.0]]])  # (2, 3, 1)
    mask = torch.tensor([[True, True, False], [True, False, False]])
    gate = torch.tensor([[0.8, 0.2], [0.4, 0.6]])
    L0 = [(_nll(0, 0, 1) + _nll(3, 1, 2)) / 2, (_nll(0, 2, 0.5) + _nll(3, 2, 0.5)) / 2]  # mean NLL per expert
    L1 = [_nll(1, 0.5, 1), _nll(1, -1, 2)]
    return mean, std, target, mask, gate, (L0, 2), (L1, 1)


def _hand_posterior(Ls, ns, ps, progress, balancing=ASSIGNMENTS["annealed"].balancing):
    """The "annealed" responsibilities by hand: per sample p_e exp(-k L_e) with k = n ** min(1, progress / 0.6);
    balanced: 3 rounds of scaling each expert's column into [floor, cap] * B/d (equal shares B/d for "annealed")
    and each row to 1; free: rows to 1; between the balancing's fade_from and until, the rows of
    balanced^(1 - s) free^s with s = (progress - fade_from) / (until - fade_from)."""
    w = [
        [p * math.exp(-(n ** min(1.0, progress / ANNEAL_FRACTION)) * le) for p, le in zip(pi, Li)]
        for Li, n, pi in zip(Ls, ns, ps)
    ]
    B, d = len(w), len(w[0])
    free = [[x / sum(row) for x in row] for row in w]
    if progress >= balancing.until:
        return free
    for _ in range(SINKHORN_ITERATIONS):
        column = [sum(w[i][e] for i in range(B)) for e in range(d)]
        kept = [min(max(c, balancing.floor * B / d), balancing.cap * B / d) for c in column]
        w = [[w[i][e] * kept[e] / column[e] for e in range(d)] for i in range(B)]
        w = [[x / sum(row) for x in row] for row in w]
    s = (
        (progress - balancing.fade_from) / (balancing.until - balancing.fade_from)
        if progress > balancing.fade_from
        else 0.0
    )
    mixed = [[held ** (1 - s) * f**s for held, f in zip(hrow, frow)] for hrow, frow in zip(w, free)]
    return [[x / sum(row) for x in row] for row in mixed]


@pytest.mark.parametrize("assignment", ["annealed", "bounded"])
def test_annealed_term_against_a_hand_computation(assignment):
    cfg = CNEPConfig(n_experts=2, a_rec=1.0, a_batch=0.0, a_ind=0.0, assignment=assignment)
    mean, std, target, mask, gate, (L0, n0), (L1, n1) = _two_sample_example()
    p = gate.tolist()
    # balanced and soft, balanced and sharper, "bounded" halfway through its fade, free and as sharp as the mixture
    for progress in (0.0, 0.3, 0.7, 1.0):
        _, terms = cnep_loss(mean, std, gate, target, mask, cfg, progress)
        r = _hand_posterior([L0, L1], [n0, n1], p, progress, ASSIGNMENTS[assignment].balancing)
        rec = [sum(re * (le - math.log(pe)) for re, le, pe in zip(ri, Li, pi)) for ri, Li, pi in zip(r, [L0, L1], p)]
        assert math.isclose(terms["rec"], (rec[0] + rec[1]) / 2 / 2, rel_tol=1e-6)  # mean over samples, then / d


@pytest.mark.parametrize("assignment", ["annealed", "bounded"])
def test_the_demonstrations_decide_which_expert_learns_and_the_samples_what_the_gate_learns(assignment):
    """Where `posterior` is given, the experts learn the responsibilities of each sample's whole demonstration and the
    gate those of the sample's own targets: the loss equals the hand computation with the demonstrations' posterior
    weighing the NLL and the samples' own posterior weighing -log p."""
    cfg = CNEPConfig(n_experts=2, a_rec=1.0, a_batch=0.0, a_ind=0.0, assignment=assignment)
    mean, std, target, mask, gate, (L0, n0), (L1, n1) = _two_sample_example()
    # both samples' targets favour expert 0 (L0, L1); their demonstrations, 40 values each, favour expert 1
    demo = torch.tensor([[1.5, 1.0], [2.0, 1.2]])
    values = torch.tensor([40.0, 40.0])
    for progress in (0.0, 0.7, 1.0):
        _, terms = cnep_loss(mean, std, gate, target, mask, cfg, progress, (demo, values))
        r = _hand_posterior(demo.tolist(), [40, 40], gate.tolist(), progress, ASSIGNMENTS[assignment].balancing)
        own = _hand_posterior([L0, L1], [n0, n1], gate.tolist(), progress, ASSIGNMENTS[assignment].balancing)
        rec = [
            sum(re * le - oe * math.log(pe) for re, oe, le, pe in zip(ri, oi, Li, pi))
            for ri, oi, Li, pi in zip(r, own, [L0, L1], gate)
        ]
        assert math.isclose(terms["rec"], (rec[0] + rec[1]) / 2 / 2, rel_tol=1e-6)
    logits = gate.log().clone().requires_grad_()
    mean = mean.clone().requires_grad_()
    cnep_loss(mean, std, torch.softmax(logits, -1), target, mask, cfg, 1.0, (demo, values))[0].backward()
    assert (logits.grad[:, 0] < 0).all()  # free and sharp: the gate is pulled towards expert 0, the targets' own
    # while expert 1 learns the samples' targets (its mean gets the gradient) and expert 0 nearly nothing
    assert mean.grad[:, 1].abs().sum() > 100 * mean.grad[:, 0].abs().sum()


def test_the_trainer_gives_the_em_assignments_the_demonstrations_and_the_papers_term_none(monkeypatch):
    import cnep.models.train
    from cnep.models.config import TrainConfig
    from cnep.models.train import fit
    from tests.models.factories import two_mode_trajectories

    posteriors = []

    def spy(*args):
        posteriors.append(args[7])
        return cnep_loss(*args)

    monkeypatch.setattr(cnep.models.train, "cnep_loss", spy)
    trajs, _ = two_mode_trajectories(n=4, T=10, seed=0)
    for assignment, given in (("bounded", True), ("paper", False), ("mixture", False)):
        posteriors.clear()
        config = CNEPConfig(n_experts=2, encoder_widths=(8,), expert_widths=(8,), assignment=assignment)
        fit(trajs, config, TrainConfig(steps=2, warmup_steps=1, val_every=2), progress=False)
        assert len(posteriors) == 2 and all((p is not None) == given for p in posteriors)


def test_annealed_gate_learns_the_posterior_at_full_strength_and_experts_learn_it_as_in_the_mixture():
    mean, std, target, mask, gate, (L0, n0), (L1, n1) = _two_sample_example()
    cfg = CNEPConfig(n_experts=2, a_rec=1.0, a_batch=0.0, a_ind=0.0, assignment="annealed")
    for progress in (0.0, 1.0):
        logits = gate.log().clone().requires_grad_()
        cnep_loss(mean, std, torch.softmax(logits, -1), target, mask, cfg, progress)[0].backward()
        r = torch.tensor(_hand_posterior([L0, L1], [n0, n1], gate.tolist(), progress))
        torch.testing.assert_close(logits.grad, (gate - r) / 2 / 2)  # (p - r) / d, mean over B = 2 samples
    # once annealed the experts' gradient is the mixture likelihood's (whose gate gradient is n_i times weaker)
    grads = {}
    for assignment in ("mixture", "annealed"):
        m = mean.clone().requires_grad_()
        cnep_loss(m, std, gate, target, mask, dataclasses.replace(cfg, assignment=assignment), 1.0)[0].backward()
        grads[assignment] = m.grad
    torch.testing.assert_close(grads["annealed"], grads["mixture"])


def test_balancing_spreads_the_batch_over_the_experts_while_the_posterior_anneals():
    # every sample is explained best by expert 0: unbalanced, expert 0 takes nearly all of the batch;
    # balanced, every expert takes close to B/d of it, and each row stays a distribution
    nll = torch.tensor([[0.0, 2.0, 3.0], [0.1, 1.0, 4.0], [0.0, 3.0, 1.0], [0.2, 2.0, 2.0]])
    log_p = torch.full((4, 3), -math.log(3.0))
    values = torch.full((4,), 4.0)
    free = annealed_posterior(log_p, nll, values, 1.0)
    held = annealed_posterior(log_p, nll, values, 0.0)
    assert free[:, 0].sum() > 3.9
    torch.testing.assert_close(held.sum(-1), torch.ones(4))
    torch.testing.assert_close(held.sum(0), torch.full((3,), 4 / 3), atol=0.05, rtol=0)
    torch.testing.assert_close(balanced(held.log(), 50).exp().sum(0), torch.full((3,), 4 / 3))  # Sinkhorn converges
    assert int(held.argmax(-1)[2]) == 2 and int(held.argmax(-1)[1]) == 1  # the next best expert takes the mass


def test_bounded_balancing_keeps_every_experts_share_between_a_floor_and_a_cap():
    # every sample is explained best by expert 0: free, expert 0 takes nearly all of the batch; bounded, no
    # expert takes more than cap * B/d (exactly, once converged) nor less than floor * B/d, each row stays a
    # distribution, and each sample's next best expert takes its mass (bounds at which the cap binds here)
    bounded = dataclasses.replace(ASSIGNMENTS["bounded"].balancing, floor=0.5, cap=1.5)
    floor, cap = bounded.floor, bounded.cap
    nll = torch.tensor([[0.0, 2.0, 3.0, 3.0], [0.1, 1.0, 4.0, 3.0], [0.0, 3.0, 1.0, 3.0], [0.2, 2.0, 2.0, 1.5]])
    log_p = torch.full((4, 4), -math.log(4.0))  # B/d = 1
    values = torch.full((4,), 4.0)
    free = annealed_posterior(log_p, nll, values, 1.0, bounded)
    held = annealed_posterior(log_p, nll, values, 0.0, bounded)
    assert free[:, 0].sum() > 3.9
    torch.testing.assert_close(held.sum(-1), torch.ones(4))
    assert held.sum(0)[0] < cap + 0.05 and (held.sum(0) > floor).all()
    converged = balanced(held.log(), 50, floor, cap).exp().sum(0)
    torch.testing.assert_close(converged[0], torch.tensor(cap))
    assert (converged >= floor).all()
    assert held.argmax(-1).tolist() == [0, 1, 2, 3]


def test_bounded_balancing_fades_out_where_annealed_balancing_stops():
    bounded, annealed = ASSIGNMENTS["bounded"].balancing, ASSIGNMENTS["annealed"].balancing
    assert [bounded.free_weight(p) for p in (0.0, 0.59, 0.6, 0.7, 0.8, 1.0)] == pytest.approx([0, 0, 0, 0.5, 1, 1])
    assert [annealed.free_weight(p) for p in (0.0, 0.59, 0.6, 1.0)] == [0, 0, 1, 1]
    # the best model is kept only once the posterior is the final one
    assert (
        ASSIGNMENTS["bounded"].settled_fraction == bounded.until
        and ASSIGNMENTS["annealed"].settled_fraction == ANNEAL_FRACTION
    )
    assert ASSIGNMENTS["paper"].settled_fraction == ASSIGNMENTS["mixture"].settled_fraction == 0.0


def test_bounded_balancing_leaves_shares_between_the_floor_and_the_cap_to_the_posterior():
    floor, cap = ASSIGNMENTS["bounded"].balancing.floor, ASSIGNMENTS["bounded"].balancing.cap
    log_r = torch.log_softmax(torch.tensor([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0], [1.0, 0.0, 1.0]]), -1)
    shares = log_r.exp().sum(0)  # about 1.42, 1.16, 1.42 of 4 samples: inside [floor, cap] * B/d = [0.67, 2.0]
    assert (shares > floor * 4 / 3).all() and (shares < cap * 4 / 3).all()
    torch.testing.assert_close(balanced(log_r, floor=floor, cap=cap), log_r)
    assert not torch.allclose(balanced(log_r), log_r, atol=1e-3)  # equal shares (annealed) move them


@pytest.mark.parametrize("assignment", ["annealed", "bounded"])
def test_balancing_of_stacked_models_is_each_models_own(assignment):
    log_r = torch.randn(3, 5, 4, generator=torch.Generator().manual_seed(0))  # k = 3 stacked models, B = 5, d = 4
    bounds = ASSIGNMENTS[assignment].balancing.floor, ASSIGNMENTS[assignment].balancing.cap
    stacked = balanced(log_r, SINKHORN_ITERATIONS, *bounds)
    for i in range(3):
        assert torch.equal(stacked[i], balanced(log_r[i], SINKHORN_ITERATIONS, *bounds))


def test_the_papers_and_the_mixtures_terms_do_not_depend_on_the_training_progress():
    mean, std, target, mask, gate, _, _ = _two_sample_example()
    for assignment in ("paper", "mixture"):
        cfg = CNEPConfig(n_experts=2, assignment=assignment)
        at = [cnep_loss(mean, std, gate, target, mask, cfg, progress)[1] for progress in (0.0, 0.5, 1.0)]
        assert at[0] == at[1] == at[2] == cnep_loss(mean, std, gate, target, mask, cfg)[1]


def test_the_trainer_gives_the_loss_the_fraction_of_training_done(monkeypatch):
    import cnep.models.train
    from cnep.models.config import TrainConfig
    from cnep.models.train import fit
    from tests.models.factories import two_mode_trajectories

    seen, posteriors = [], []

    def spy(*args):
        seen.append(args[6])  # progress
        posteriors.append(args[7])  # the demonstrations' NLL and values (models.train.demonstration_nll)
        return cnep_loss(*args)

    monkeypatch.setattr(cnep.models.train, "cnep_loss", spy)
    trajs, _ = two_mode_trajectories(n=4, T=10, seed=0)
    fit(
        trajs,
        CNEPConfig(n_experts=2, encoder_widths=(8,), expert_widths=(8,), assignment="annealed"),
        TrainConfig(steps=4, warmup_steps=1, val_every=2),
        progress=False,
    )
    assert seen == [0.0, 0.25, 0.5, 0.75]
    assert all(nll.shape == (32, 2) and torch.equal(values, torch.full((32,), 10.0)) for nll, values in posteriors)
