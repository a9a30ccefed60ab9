"""Training several CNEPs of one shape in one batched computation: one step advances k models.

The evaluation trains dozens of small networks (seeds, loss ablations); one of them leaves the CPU
mostly waiting on per-kernel overhead (a step is ~150 small kernels). Here the parameters of k
models are stacked along a new first dimension, and every layer of all k models runs as one batched
matrix product (`torch.baddbmm`); the loss (`models.loss.loss_terms`, the function `models.Trainer`'s
loss calls), the gradient clipping and one fused Adam also run once per step for all of them, so the
overhead is paid once per step.

Each model keeps everything that makes it itself: its own data, batch generator (seeded), loss
weights and assignment, gradient clipping (its own norm), Adam state, validation, early stop and
best-model keeping (its own `Trainer`). With one torch thread, a model trained here ends bit-identical
to the same run of `models.fit` (tests/models/test_batched.py): the stacked products, reductions and
element-wise updates compute each model's slice with the same kernels and in the same order as the
single model's do. One condition: every per-model product must have contraction x rows x
columns >= 400 (true for any real CNEP: batch 32, widths 128); below that torch's batched product
switches to its own small-matrix loop, whose sums differ from BLAS's in the last bits.

Models can train together when `batch_key` agrees: the same network shape (`ARCHITECTURE_FIELDS`),
the same TrainConfig apart from the seed, and batches of the same shape.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cnep.models.assignments import Assignment
from cnep.models.cnep import CNEP
from cnep.models.config import CNEPConfig, ConditioningPolicy, TrainConfig
from cnep.models.errors import ConfigError
from cnep.models.loss import loss_terms
from cnep.models.sampler import DEMONSTRATION_STEPS
from cnep.models.threads import torch_threads
from cnep.models.train import (
    Trainer,
    decay_observed_only,
    demonstration_nll,
    finish_fit,
    make_optimizer,
    prepare_fit,
    set_learning_rate,
)

# What must agree for two networks to stack (the loss weights a_rec, a_batch, a_ind may differ).
ARCHITECTURE_FIELDS = (
    "columns",
    "n_experts",
    "encoder_widths",
    "expert_widths",
    "min_std",
    "time_frequencies",
    "feature_components",
)
MAX_MODELS = 8  # models per batched computation in `fit_many`


def batch_key(trainer: Trainer) -> tuple:
    """Trainers with equal keys can train together: network shape, schedule (all but the seed and the gate's
    learning rate), batch shape."""
    T = trainer.train.longest
    cfg = trainer.cfg
    return (
        tuple(getattr(trainer.model.config, f) for f in ARCHITECTURE_FIELDS),
        dataclasses.replace(cfg, seed=0, gate_lr_scale=None),
        trainer.online[1:],
        min(cfg.n_max, T),
        min(cfg.m_max, T),
        min(DEMONSTRATION_STEPS, T),
    )


class StackedLinear(torch.autograd.Function):
    """k `nn.Linear` layers at once: x (k, R, in), weight (k, out, in), bias (k, out) -> (k, R, out).

    The backward pass forms the same products as nn.Linear's: its weight gradient is grad^T @ x (torch
    picks that order for a transposed weight), where autograd's batched product would form (x^T @ grad)^T,
    which sums in another order (last bits differ).
    """

    @staticmethod
    def forward(ctx, x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(x, weight)
        return torch.baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2))  # (k, R, out)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        x, weight = ctx.saved_tensors
        return grad.bmm(weight), grad.transpose(1, 2).bmm(x), grad.sum(1)  # (k, R, in), (k, out, in), (k, out)


class StackedCNEP:
    """The parameters of k CNEPs of one shape, stacked (k, ...), and their forward pass as batched products.

    It computes exactly `models.CNEP.forward` for each model (same operations, same order); `names`
    are the CNEP's parameter names, `params[name]` the stacked leaf tensors that the optimiser updates.
    """

    def __init__(self, models: Sequence[CNEP]) -> None:
        self.base = models[0]  # the shared shape: config, time frequencies, layer order
        self.names = [name for name, _ in self.base.named_parameters()]
        per_model = [dict(m.named_parameters()) for m in models]
        self.params = {n: torch.stack([p[n].detach() for p in per_model]).requires_grad_() for n in self.names}
        self.encoder_layers = [i for i, layer in enumerate(self.base.encoder) if isinstance(layer, nn.Linear)]
        # each model's own projection of its observed-only columns (fitted on its own data): (n, K) each, or none
        self.projections = [m.feature_projection for m in models if m.components is not None]

    def __len__(self) -> int:
        return len(next(iter(self.params.values())))

    def __call__(
        self,
        obs: torch.Tensor,
        obs_mask: torch.Tensor,
        query: torch.Tensor,
        latent: bool = False,
        keep: torch.Tensor | None = None,
    ):
        """obs (k, B, N, 1+obs_dim), obs_mask (k, B, N), query (k, B, M, 1+dq) -> mean, std (k, B, d, M, dy),
        gate (k, B, d); with `latent`, the latent r (k, B, H) too; keep (k, B, N, ...): the observed-only dropout
        (as CNEP.forward)."""
        r = self.encode(obs, obs_mask, keep)  # (k, B, H)
        logits = StackedLinear.apply(r, self.params["gate.weight"], self.params["gate.bias"])  # (k, B, d)
        mean, std = self.decode(r, query)
        gate = torch.softmax(logits, dim=-1)
        return (mean, std, gate, r) if latent else (mean, std, gate)

    def encode(self, obs: torch.Tensor, obs_mask: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
        """CNEP.encode for k models: masked mean of the encodings, (k, B, N, 1+obs_dim) -> (k, B, H)."""
        k, B, N, _ = obs.shape
        w = obs_mask.to(obs.dtype).unsqueeze(-1)  # (k, B, N, 1)
        if self.projections:  # each model's product as the lone model computes it
            obs = torch.stack([self.base.project(o, p) for o, p in zip(obs, self.projections)])  # (k, B, N, width)
        x = self.base.dropped(self.base.embed_time(obs), keep).view(k, B * N, -1)  # (k, B*N, in)
        for j, i in enumerate(self.encoder_layers):
            if j:
                x = F.relu(x)
            x = StackedLinear.apply(
                x, self.params[f"encoder.{i}.weight"], self.params[f"encoder.{i}.bias"]
            )  # (k, B*N, out)
        enc = x.view(k, B, N, -1) * w  # (k, B, N, H); padded rows contribute exactly 0
        return enc.sum(2) / w.sum(2).clamp_min(1.0)  # (k, B, H)

    def decode(self, r: torch.Tensor, query: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """CNEP.decode (models.cnep.Experts) for k models: r (k, B, H), query (k, B, M, dq) -> mean, std
        (k, B, d, M, dy)."""
        k, B, M, _ = query.shape
        d, dy = self.base.n_experts, self.base.config.columns.out_dim
        P = self.params
        q = self.base.embed_time(query).view(k, B * M, -1)  # (k, B*M, dq)
        latent = torch.bmm(r, P["experts.first_r"]) + P["experts.first_b"].unsqueeze(1)  # (k, B, d*w0)
        h = latent.unsqueeze(2) + torch.bmm(q, P["experts.first_q"]).view(k, B, M, -1)  # (k, B, M, d*w0)
        x = h.view(k, B * M, d, -1).transpose(1, 2).reshape(k * d, B * M, -1)  # (k*d, B*M, w0)
        for i in range(len(self.base.experts.weights)):
            w, b = P[f"experts.weights.{i}"], P[f"experts.biases.{i}"]  # (k, d, a, b), (k, d, 1, b)
            x = torch.baddbmm(b.flatten(0, 1), F.relu(x), w.flatten(0, 1))  # (k*d, B*M, width)
        out = x.view(k, d, B, M, 2 * dy).transpose(1, 2)  # (k, B, d, M, 2dy)
        mean, raw = out.split(dy, dim=-1)  # (k, B, d, M, dy) each
        return mean, self.base.config.min_std + F.softplus(raw)

    @torch.no_grad()
    def copy_to(self, i: int, model: CNEP) -> None:
        """Write model `i`'s current parameters into `model` (a CNEP of the same shape)."""
        for name, p in model.named_parameters():
            p.copy_(self.params[name][i])


class BatchedTrainer:
    """k fresh `models.Trainer`s of one `batch_key`, stepped together; each keeps its data, seed, loss and history.

    One step is one computation for all models still training: the stacked forward pass, the loss
    (`models.loss.loss_terms` over the stack, by assignment), one backward pass, each model's gradient
    clipped by its own norm, and one fused Adam over every model's parameter slices (views of the stacks,
    so Adam treats each slice as the lone model's tensor: same elements, same vectorised loop). A model
    that stops early leaves the stack at that validation. `run()` leaves each Trainer as its own `run()`
    would: history, best state, final weights in its model. Not resumable (no state_dict): the evaluation
    trains start to end.
    """

    def __init__(self, trainers: Sequence[Trainer]) -> None:
        keys = {batch_key(t) for t in trainers}
        if len(keys) != 1 or any(t.step for t in trainers):
            raise ConfigError(
                "BatchedTrainer needs fresh trainers of one network shape, schedule and batch shape "
                f"(models.batched.batch_key); got {len(keys)} different key(s) over {len(trainers)} trainers."
            )
        self.trainers = list(trainers)
        self.cfg = trainers[0].cfg
        self.step = 0
        self.active: list[int] = []  # the trainers still training, in stack order
        self.views: list[
            dict[str, torch.Tensor]
        ] = []  # per active model: its slice (a view) of every stacked parameter
        self.optimizer: torch.optim.Adam | None = None
        self._stack(list(range(len(trainers))))

    def _stack(self, active: list[int]) -> None:
        """Stack the parameters of trainers `active` (from their models) with one Adam over their slices; Adam's
        state (moments, step) carries over for models that were already in the stack."""
        old = {(i, name): view for i, views in zip(self.active, self.views) for name, view in views.items()}
        old_state = self.optimizer.state if self.optimizer is not None else {}
        self.active = active
        configs = [self.trainers[i].model.config for i in active]
        self.assignments = [c.assigned for c in configs]
        self.weights = torch.tensor([[c.a_rec, c.a_batch, c.a_ind] for c in configs], device=self.trainers[0].device)
        self.net = StackedCNEP([self.trainers[i].model for i in active])
        self.views = [{name: p[j].detach() for name, p in self.net.params.items()} for j in range(len(active))]
        network = [v for views in self.views for name, v in views.items() if not name.startswith("gate.")]
        scales = [self.trainers[i].cfg.gate_lr_scale for i in active]  # each model's own (its assignment's)
        gates = [
            (
                [
                    v
                    for views, s in zip(self.views, scales)
                    if s == scale
                    for name, v in views.items()
                    if name.startswith("gate.")
                ],
                scale,
            )
            for scale in sorted(set(scales))
        ]
        self.optimizer = make_optimizer([(network, 1.0), *gates], self.cfg.lr)
        for i, views in zip(active, self.views):
            for name, view in views.items():
                if (i, name) in old:
                    self.optimizer.state[view] = old_state[old[i, name]]

    def train_step(self) -> list[dict[str, float]]:
        """One optimiser step of every active model; returns each one's loss terms (as `Trainer.train_step`)."""
        for j, i in enumerate(self.active):
            if self.step in self.trainers[i].split_at:  # on its slices of the stack, as `Trainer.train_step` does
                self.net.copy_to(j, self.trainers[i].model)
                state = {name: self.optimizer.state.get(view, {}) for name, view in self.views[j].items()}
                self.trainers[i].split_idle(self.views[j], state)
        batches = [self.trainers[i].next_batch() for i in self.active]  # each from its own generator
        stacked = {
            f: torch.stack([getattr(b, f) for b in batches])
            for f in ("obs", "obs_mask", "query", "target", "target_mask")
        }
        keep = None if batches[0].keep is None else torch.stack([b.keep for b in batches])  # the same for every model
        mean, std, gate, r = self.net(stacked["obs"], stacked["obs_mask"], stacked["query"], latent=True, keep=keep)
        posterior = None
        if any(a.uses_demonstration for a in self.assignments):  # each from its own model's demonstrations
            parts = zip(*(self.trainers[i].demonstration(b) for i, b in zip(self.active, batches)))
            demonstration = tuple(torch.stack(part) for part in parts)  # (k, B, P, ...) each
            posterior = demonstration_nll(self.net, r, demonstration)
        terms = stacked_loss_terms(
            mean,
            std,
            gate,
            stacked["target"],
            stacked["target_mask"],
            self.assignments,
            self.step / self.cfg.steps,
            posterior,
            self.cfg.nll_beta,
        )  # name -> (k,)
        a = self.weights
        total = a[:, 0] * terms["rec"] - a[:, 1] * terms["batch_entropy"] + a[:, 2] * terms["ind_entropy"]  # (k,)
        params = self.net.params
        for p in params.values():
            if p.grad is not None:
                p.grad.zero_()
        total.sum().backward()  # d(sum)/d(loss_i) = 1: each model gets exactly its own gradient
        if self.step < self.trainers[0].freeze_steps:  # Adam moments stay 0, so the gates do not move
            for name in ("gate.weight", "gate.bias"):
                params[name].grad.zero_()
        clip_each(list(params.values()), self.cfg.grad_clip)
        for j, views in enumerate(self.views):
            for name, view in views.items():
                view.grad = params[name].grad[j]
        set_learning_rate(self.optimizer, self.step, self.cfg)
        self.optimizer.step()
        decayed = self.trainers[self.active[0]].decayed  # the same columns for every model of the stack
        decay_observed_only(params["encoder.0.weight"], decayed, self.optimizer, self.cfg.observed_only_decay)
        self.step += 1
        values = torch.stack([total, terms["rec"], terms["batch_entropy"], terms["ind_entropy"]], 1).tolist()
        usage = gate.detach().mean(-2).tolist()  # (k, d)
        return [
            {"loss": v[0], "rec": v[1], "batch_entropy": v[2], "ind_entropy": v[3], "usage": u}
            for v, u in zip(values, usage)
        ]

    def run(self, until: int | None = None) -> None:
        """Train up to step `until` (default: the end of the schedule), validating and stopping each model as its
        own Trainer would; each Trainer's model holds its current weights when this returns."""
        until = self.cfg.steps if until is None else min(until, self.cfg.steps)
        while self.step < until and self.active:
            terms = self.train_step()
            for i in self.active:
                self.trainers[i].step = self.step
            if not self.trainers[self.active[0]].validation_due():
                continue
            for j, i in enumerate(self.active):
                self.net.copy_to(j, self.trainers[i].model)
            stopped = {i for i, t in zip(self.active, terms) if self.trainers[i].after_step(t)}
            going_on = [i for i in self.active if i not in stopped]
            if not going_on:
                self.active = []
            elif stopped:  # their models hold the weights of this validation; the rest go on without them
                self._stack(going_on)
        for j, i in enumerate(self.active):
            self.net.copy_to(j, self.trainers[i].model)


def stacked_loss_terms(
    mean: torch.Tensor,
    std: torch.Tensor,
    gate: torch.Tensor,
    target: torch.Tensor,
    target_mask: torch.Tensor,
    assignments: Sequence[Assignment],
    progress: float,
    posterior: tuple[torch.Tensor, torch.Tensor] | None = None,
    beta: float = 0.0,
) -> dict[str, torch.Tensor]:
    """`models.loss.loss_terms` of k stacked models (leading dimension k), model j with `assignments[j]` -> name ->
    (k,); posterior: each model's (nll (k, B, d), values (k, B)) of its samples' demonstrations
    (`models.train.demonstration_nll`), read by the assignments that use it; beta: as in `models.loss.expert_nll`."""
    groups = {a: [j for j, x in enumerate(assignments) if x == a] for a in dict.fromkeys(assignments)}
    if len(groups) == 1:
        return loss_terms(mean, std, gate, target, target_mask, assignments[0], progress, posterior, beta)
    parts = [
        loss_terms(
            mean[idx],
            std[idx],
            gate[idx],
            target[idx],
            target_mask[idx],
            a,
            progress,
            None if posterior is None else tuple(x[idx] for x in posterior),
            beta,
        )
        for a, idx in groups.items()
    ]
    order = torch.tensor([j for idx in groups.values() for j in idx]).argsort().to(gate.device)
    return {name: torch.cat([part[name] for part in parts])[order] for name in parts[0]}


@torch.no_grad()
def clip_each(params: Sequence[torch.Tensor], max_norm: float) -> None:
    """`torch.nn.utils.clip_grad_norm_` for each of k stacked models (leading dimension k), by its own norm.

    The same operations per model: each tensor's norm, the norm of those norms, the coefficient clamped to 1,
    every gradient multiplied by it.
    """
    grads = [p.grad for p in params]
    norms = torch.stack([torch.linalg.vector_norm(g.flatten(1), dim=1) for g in grads], 1)  # (k, tensors)
    coef = (max_norm / (torch.linalg.vector_norm(norms, dim=1) + 1e-6)).clamp(max=1.0)  # (k,)
    for g in grads:
        g.mul_(coef.view(-1, *[1] * (g.dim() - 1)))


@dataclass(frozen=True)
class FitRun:
    """The arguments of one `models.fit` call."""

    trajectories: Sequence[np.ndarray]
    config: CNEPConfig
    train_config: TrainConfig = TrainConfig()
    val_trajectories: Sequence[np.ndarray] | None = None
    conditioning: ConditioningPolicy = ConditioningPolicy()


def fit_many(runs: Sequence[FitRun], max_models: int = MAX_MODELS) -> list[tuple[CNEP, list[dict]]]:
    """`models.fit` for each run (no progress bar, on its `threads`), runs of one `batch_key` trained together, up
    to `max_models` at once.

    Returns, in order, what `fit` returns for each run: the best model and its history.
    """
    prepared = [prepare_fit(r.trajectories, r.config, r.train_config, r.val_trajectories, r.conditioning) for r in runs]
    groups: dict[tuple, list[Trainer]] = {}
    for trainer, _ in prepared:
        groups.setdefault(batch_key(trainer), []).append(trainer)
    for trainers in groups.values():
        for start in range(0, len(trainers), max_models):
            chunk = trainers[start : start + max_models]
            with torch_threads(chunk[0].cfg.threads):  # one count per key: `threads` is part of it
                if len(chunk) == 1:
                    chunk[0].run(progress=False)
                else:
                    BatchedTrainer(chunk).run()
    return [finish_fit(trainer, split) for trainer, split in prepared]
