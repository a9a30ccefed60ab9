"""The EM assignments' split step: an idle expert takes a copy of a busy one while the posterior is balanced.

The balanced posterior (models.assignments) keeps every expert's share of each batch, but an expert can keep its
share by learning a little of every behaviour while two behaviours share another expert; once the posterior is free it
loses even that, and the model ends with one expert unused. At SPLIT_CHECKS, from the gate's unfreezing
to the start of the balancing's fade, each training demonstration, conditioned on itself, is counted for the expert
its gate has decided for (`owners`). When the expert counted least has below IDLE_SHARE of an equal share and the
one counted most above BUSY_SHARE, the idle expert becomes a copy of the busy one (`split`): its decoder weights with
a little seeded noise, its Adam moments, its gate row, and each of the two gate logits lowered by log 2, so the gate
gives the pair what it gave the busy expert. The balancing then makes the two copies divide the busy expert's
demonstrations between them, as k-means splits a large cluster.
"""

from __future__ import annotations

import math

import torch

from cnep.models.sampler import TrajectoryStack

SPLIT_CHECKS = (0.35, 0.4, 0.45, 0.5, 0.55)  # fractions of training at which `split_if_idle` looks
IDLE_SHARE = 0.5  # an expert decided for by fewer demonstrations than this x an equal share is idle ...
BUSY_SHARE = 1.5  # ... and takes a copy of the one decided for by more than this x an equal share
NOISE = 0.01  # the copy's noise: this x the standard deviation of each copied tensor
_CHUNK = 256  # demonstrations encoded at once by `owners`


def split_steps(steps: int, first: int, last: float) -> frozenset[int]:
    """The steps of SPLIT_CHECKS in a run of `steps`, from step `first` (the gate's unfreezing) and before the
    fraction `last` (the balancing's fade)."""
    return frozenset(s for f in SPLIT_CHECKS if f < last and (s := int(f * steps)) >= first)


@torch.no_grad()
def owners(model, stack: TrajectoryStack) -> torch.Tensor:
    """How many demonstrations of `stack` each expert's gate has decided for, each conditioned on itself (at most
    `models.sampler.DEMONSTRATION_STEPS` of its steps) -> (d,) long. Decided: the gate gives the expert at least
    (1 + 1/d) / 2, halfway from undecided (1/d) to sure, so that a gate still close to uniform decides nothing.
    model: a CNEP (or one that delegates to it)."""
    d = model.n_experts
    device = next(model.parameters()).device
    counts = torch.zeros(d, dtype=torch.long, device=device)
    for start in range(0, len(stack), _CHUNK):
        obs, mask = (x.to(device) for x in stack.context(torch.arange(start, min(start + _CHUNK, len(stack)))))
        top, expert = torch.softmax(model.gate(model.encode(obs, mask)), -1).max(-1)
        counts += torch.bincount(expert[top >= (1 + 1 / d) / 2], minlength=d)
    return counts


def expert_part(name: str, p: torch.Tensor, expert: int, d: int) -> tuple:
    """The index of `expert`'s part of CNEP parameter `name` (models.cnep.Experts' stacked layers, the gate's rows)."""
    if name.startswith("experts.first_"):  # first_r, first_q (in, d * w0), first_b (d * w0,): experts side by side
        w0 = p.shape[-1] // d
        return (..., slice(expert * w0, (expert + 1) * w0))
    return (expert,)  # experts.weights.i (d, a, b), experts.biases.i (d, 1, b), gate.weight (d, H), gate.bias (d,)


@torch.no_grad()
def split(
    params: dict[str, torch.Tensor], state: dict[str, dict], idle: int, busy: int, generator: torch.Generator
) -> None:
    """Make expert `idle` a copy of expert `busy`, in place. params: a CNEP's parameters by name (or views of them);
    state: each one's Adam state by the same names, whose moments are copied where there are any."""
    d = params["gate.bias"].shape[-1]
    for name, p in params.items():
        if not name.startswith(("experts.", "gate.")):
            continue
        src, dst = expert_part(name, p, busy, d), expert_part(name, p, idle, d)
        p[dst] = p[src]
        if not name.startswith("gate.") and p[src].numel() > 1:  # (a lone number has no spread to scale noise by)
            p[dst] += NOISE * p[src].std() * torch.randn(p[src].shape, generator=generator).to(p.device)
        for moment in ("exp_avg", "exp_avg_sq"):
            if moment in state.get(name, {}):
                state[name][moment][dst] = state[name][moment][src]
    params["gate.bias"][[idle, busy]] -= math.log(2.0)


def split_if_idle(
    model, stack: TrajectoryStack, params: dict[str, torch.Tensor], state: dict[str, dict], seed: int, step: int
) -> tuple[int, int, list[int]] | None:
    """`split` the idle expert from the busy one if `owners` finds one of each; returns (idle, busy, the counts
    before), or None. model: the CNEP whose parameters `params` are (or hold model's values, models.batched); the
    noise is seeded by (seed, step)."""
    counts = owners(model, stack)
    share = len(stack) / len(counts)
    idle, busy = int(counts.argmin()), int(counts.argmax())
    if not (counts[idle] < IDLE_SHARE * share and counts[busy] > BUSY_SHARE * share):
        return None
    split(params, state, idle, busy, torch.Generator().manual_seed(seed * 1_000_003 + step))
    return idle, busy, counts.tolist()
