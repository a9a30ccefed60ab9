import math

import torch

from models.config import CNEPConfig
from models.loss import cnep_loss, entropy, expert_nll


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


def test_entropy_is_stable_at_zero_and_per_row():
    p = torch.tensor([[1.0, 0.0], [0.5, 0.5]], requires_grad=True)
    h = entropy(p)
    torch.testing.assert_close(h, torch.tensor([0.0, math.log(2)]))
    h.sum().backward()
    assert torch.isfinite(p.grad).all()


def test_total_loss_terms_and_signs_against_a_hand_computation():
    cfg = CNEPConfig(n_experts=2, a_rec=2.0, a_batch=3.0, a_ind=5.0)
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
    loss = {name: cnep_loss(*args[:2], g, *args[2:], cfg)[0].item() for name, g in
            [("collapsed", collapsed), ("spread", spread), ("unsure", unsure)]}
    assert loss["spread"] < loss["collapsed"]
    assert loss["spread"] < loss["unsure"]
