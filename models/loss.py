"""The CNEP loss: a reconstruction term, batch entropy (maximised), individual entropy (minimised).

    L_e     = mean over targets and output dims of -log N(y | mu_e, sigma_e)        (B, d)
    L_rec   = mean_i (1/d) sum_e p_ie L_ie                                   (term GATE_WEIGHTED: "paper")
            = mean_i (1/(d n_i)) (-log sum_e p_ie exp(-S_ie))                (term MIXTURE: "mixture")
            = mean_i (1/d) sum_e (r_ie L_ie - q_ie log p_ie), r, q detached   (term POSTERIOR: "annealed", "bounded")
    L_batch = H(mean_i p_i)            entropy of the batch-mean gate distribution
    L_ind   = mean_i H(p_i)            mean entropy of each sample's gate distribution
    L_total = a_rec L_rec - a_batch L_batch + a_ind L_ind

n_i: the target values of sample i (targets x output dims); S_ie = n_i L_ie. The mixture's responsibilities
r_ie = p_ie exp(-S_ie) / sum_k p_ik exp(-S_ik) let the targets decide which expert learns them. The posterior term is
expectation-maximisation: r_ie = softmax_e(log p_ie - k_i D_ie), D_ie expert e's mean NLL of the whole demonstration
sample i was drawn from (`models.train.demonstration_nll`), k_i rising from 1 to that demonstration's number of values
(`annealed_sharpness`), balanced over the batch as the assignment's `Balancing` says (`balanced`); the gate learns q,
the same posterior from the sample's own targets. Dividing by n_i and d keeps the gradients on the paper's per-value
scale and `a_rec`'s rescaling with d meaning the same; with one expert every term is mean_i L_i. The paper prints
`+ a_batch L_batch`, but its text and the authors' code maximise batch entropy, so it is subtracted. Entropies use
clamped logs per row: a probability that underflows to 0 contributes 0. Which assignment to choose, and why each
works as it does: docs/concepts.md.
"""

from __future__ import annotations

import math

import torch

from cnep.models.assignments import (
    ANNEAL_FRACTION,
    ASSIGNMENTS,
    GATE_WEIGHTED,
    MIXTURE,
    POSTERIOR,
    Assignment,
    Balancing,
)
from cnep.models.config import CNEPConfig

_TINY = 1e-12
_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)
SINKHORN_ITERATIONS = 3  # the EM assignments: balancing steps of the posterior over the batch while it anneals


def entropy(p: torch.Tensor) -> torch.Tensor:
    """Shannon entropy (nats) over the last dimension: (..., d) -> (...)."""
    return -(p * p.clamp_min(_TINY).log()).sum(-1)


def expert_nll(
    mean: torch.Tensor, std: torch.Tensor, target: torch.Tensor, target_mask: torch.Tensor, beta: float = 0.0
) -> torch.Tensor:
    """Mean Gaussian NLL per sample and expert over the real targets and output dims.

    mean, std (..., B, d, M, dy); target (..., B, M, dy); target_mask (..., B, M) bool -> (..., B, d).
    Leading dimensions (k stacked models, models.batched) are computed slice by slice as without them.
    beta: each value's NLL weighted by its predicted variance ** beta, not differentiated (the beta-NLL of Seitzer
    et al., 2022). With plain NLL (0) a value predicted with a small std outweighs one the model finds hard by the
    ratio of their variances, and the hard one's mean stops being learned: its std grows to cover it instead.
    """
    z = (target.unsqueeze(-3) - mean) / std  # (B, d, M, dy)
    nll = 0.5 * z**2 + std.log() + _HALF_LOG_2PI  # (B, d, M, dy)
    if beta:
        nll = nll * std.detach() ** (2 * beta)
    w = target_mask.to(nll.dtype)[..., None, :, None]  # (B, 1, M, 1)
    count = w.sum((-2, -1)) * mean.shape[-1]  # (B, 1)
    return (nll * w).sum((-2, -1)) / count.clamp_min(1.0)  # (B, d)


def annealed_sharpness(values: torch.Tensor, progress: float) -> torch.Tensor:
    """k_i of the "annealed" posterior: n_i ** min(1, progress / ANNEAL_FRACTION); values (B,) -> (B,).

    progress: the fraction of training done (step / steps), in [0, 1].
    """
    exponent = min(1.0, max(0.0, progress) / ANNEAL_FRACTION)
    # in float64: a power's last float32 bit can depend on where the element falls in a vectorised loop, and a
    # model trained in a stack (models.batched) must match the same model trained alone bit for bit
    return (values.double().clamp_min(1.0) ** exponent).to(values.dtype)


def balanced(
    log_r: torch.Tensor, iterations: int = SINKHORN_ITERATIONS, floor: float = 1.0, cap: float = 1.0
) -> torch.Tensor:
    """Balancing of log responsibilities (..., B, d) over the batch, in log space -> (..., B, d): alternately
    bring each expert's column mass into [`floor`, `cap`] * B/d (a column below the floor is raised to it,
    one above the cap lowered to it, the others keep the posterior's mass) and scale each sample's row to 1
    (the last step). Each half-step is the nearest distribution (in KL) meeting its own constraint; `floor`
    = `cap` = 1 (the default) gives Sinkhorn's steps to equal shares, B/d each. The first column step acts
    on the posterior as given (log p - k L, rows not yet normalised): where every column lies on the same
    side of the bounds, as with a sharp posterior, that step equalises them as Sinkhorn's would, and the
    bounds act from the second step on."""
    B, d = log_r.shape[-2:]
    low, high = math.log(floor * B / d), math.log(cap * B / d)
    for _ in range(iterations):
        column = torch.logsumexp(log_r, -2, keepdim=True)  # (..., 1, d) log mass per expert
        if floor == cap:
            log_r = log_r - column + low
        else:
            log_r = log_r + (low - column).clamp_min(0.0) + (high - column).clamp_max(0.0)
        log_r = log_r - torch.logsumexp(log_r, -1, keepdim=True)
    return log_r


def annealed_posterior(
    log_p: torch.Tensor,
    nll: torch.Tensor,
    values: torch.Tensor,
    progress: float,
    balancing: Balancing = ASSIGNMENTS["annealed"].balancing,
) -> torch.Tensor:
    """The "annealed" responsibilities r (B, d), detached: softmax_e(log p_ie - k_i L_ie), balanced over the
    batch (`balanced` within the `balancing` bounds) as its schedule says. log_p, nll (B, d); values (B,)."""
    k = annealed_sharpness(values, progress).unsqueeze(-1)  # (B, 1)
    log_r = (log_p - k * nll).detach()
    s = balancing.free_weight(progress)
    if s < 1.0:
        held = balanced(log_r, SINKHORN_ITERATIONS, balancing.floor, balancing.cap)
        log_r = held if s == 0.0 else (1.0 - s) * held + s * (log_r - torch.logsumexp(log_r, -1, keepdim=True))
    return torch.softmax(log_r, dim=-1)


def gate_weighted(nll: torch.Tensor, gate: torch.Tensor, values: torch.Tensor, **_) -> torch.Tensor:
    """The paper's L_rec: mean_i (1/d) sum_e p_ie L_ie; shapes as in `reconstruction`."""
    return (gate * nll).sum(-1).mean(-1) / gate.shape[-1]


def mixture(nll: torch.Tensor, gate: torch.Tensor, values: torch.Tensor, **_) -> torch.Tensor:
    """The mixture's L_rec: mean_i (1/(d n_i)) (-log sum_e p_ie exp(-S_ie)); shapes as in `reconstruction`."""
    n = values.clamp_min(1.0).unsqueeze(-1)  # (B, 1)
    log_joint = gate.clamp_min(_TINY).log() - n * nll  # (B, d): log p_ie - S_ie
    return (-torch.logsumexp(log_joint, dim=-1) / n[..., 0]).mean(-1) / gate.shape[-1]


def posterior_em(
    nll: torch.Tensor,
    gate: torch.Tensor,
    values: torch.Tensor,
    *,
    balancing: Balancing,
    progress: float,
    posterior: tuple[torch.Tensor, torch.Tensor] | None,
) -> torch.Tensor:
    """The EM assignments' L_rec: mean_i (1/d) sum_e (r_ie L_ie - q_ie log p_ie); shapes as in `reconstruction`."""
    log_p = gate.clamp_min(_TINY).log()  # (B, d)
    own = annealed_posterior(log_p, nll, values, progress, balancing)  # (B, d), detached: what the gate learns
    r = own if posterior is None else annealed_posterior(log_p, *posterior, progress, balancing)  # the experts'
    return ((r * nll).sum(-1) - (own * log_p).sum(-1)).mean(-1) / gate.shape[-1]


# Each reconstruction term (models.assignments.Assignment.term) by name.
RECONSTRUCTIONS = {GATE_WEIGHTED: gate_weighted, MIXTURE: mixture, POSTERIOR: posterior_em}


def reconstruction(
    nll: torch.Tensor,
    gate: torch.Tensor,
    values: torch.Tensor,
    assignment: Assignment,
    progress: float = 1.0,
    posterior: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """L_rec of `assignment`: nll (..., B, d) mean NLL per value, gate (..., B, d), values (..., B) target values
    per sample -> (...); progress: the fraction of training done (only the EM assignments depend on it);
    posterior: (nll (..., B, d), values (..., B)) of each sample's whole demonstration, from which the EM
    assignments compute the experts' responsibilities (`models.train.demonstration_nll`; the sample's own targets
    when None); their gate always learns the responsibilities of the sample's own targets."""
    term = RECONSTRUCTIONS[assignment.term]
    return term(nll, gate, values, balancing=assignment.balancing, progress=progress, posterior=posterior)


def loss_terms(
    mean: torch.Tensor,
    std: torch.Tensor,
    gate: torch.Tensor,
    target: torch.Tensor,
    target_mask: torch.Tensor,
    assignment: Assignment,
    progress: float = 1.0,
    posterior: tuple[torch.Tensor, torch.Tensor] | None = None,
    beta: float = 0.0,
) -> dict[str, torch.Tensor]:
    """L_rec, L_batch and L_ind as tensors (...): shapes and beta as in `expert_nll`, gate (..., B, d); posterior as
    in `reconstruction`. Leading dimensions are k stacked models (models.batched), each computed exactly as alone."""
    nll = expert_nll(mean, std, target, target_mask, beta)  # (B, d)
    values = target_mask.to(nll.dtype).sum(-1) * mean.shape[-1]  # (B,) target values per sample
    return {
        "rec": reconstruction(nll, gate, values, assignment, progress, posterior),
        "batch_entropy": entropy(gate.mean(-2)),
        "ind_entropy": entropy(gate).mean(-1),
    }


def cnep_loss(
    mean: torch.Tensor,
    std: torch.Tensor,
    gate: torch.Tensor,
    target: torch.Tensor,
    target_mask: torch.Tensor,
    config: CNEPConfig,
    progress: float = 1.0,
    posterior: tuple[torch.Tensor, torch.Tensor] | None = None,
    beta: float = 0.0,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Total loss and its terms as floats (for logs). Shapes and beta as in `expert_nll`; gate (B, d); progress: the
    fraction of training done (step / steps; the "annealed" assignment's schedule); posterior: as in
    `reconstruction`."""
    terms = loss_terms(mean, std, gate, target, target_mask, config.assigned, progress, posterior, beta)
    total = config.a_rec * terms["rec"] - config.a_batch * terms["batch_entropy"] + config.a_ind * terms["ind_entropy"]
    return total, {"loss": total.item(), **{name: term.item() for name, term in terms.items()}}
