"""Training several CNEPs of one shape in one batched computation: one step advances k models.

The evaluation trains dozens of small networks (seeds, loss ablations); one of them leaves the CPU
mostly waiting on per-kernel overhead (a step is ~150 small kernels). Here the parameters of k
models are stacked along a new first dimension, and every layer of all k models runs as one batched
matrix product (`torch.baddbmm`), so the overhead is paid once per step for all of them.

Each model keeps everything that makes it itself: its own data, batch generator (seeded), loss
weights (`cnep_loss` is called per model, the very function `models.Trainer` calls), gradient clipping
(its own norm), validation and best-model keeping (its own `Trainer`). With one torch thread, a model
trained here ends bit-identical to the same run of `models.fit` (tests/models/test_batched.py): the
stacked products compute each model's slice with the same kernels and in the same order as the
single model's layers do. One condition: every per-model product must have contraction x rows x
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

from models.cnep import CNEP
from models.config import CNEPConfig, TrainConfig
from models.errors import ConfigError
from models.loss import cnep_loss
from models.train import Trainer, finish_fit, make_optimizer, prepare_fit, set_learning_rate

# What must agree for two networks to stack (the loss weights a_rec, a_batch, a_ind may differ).
ARCHITECTURE_FIELDS = ("layout", "n_experts", "encoder_widths", "expert_widths", "min_std", "time_frequencies")
MAX_MODELS = 8  # models per batched computation in `fit_many`


def batch_key(trainer: Trainer) -> tuple:
    """Trainers with equal keys can train together: network shape, schedule (all but the seed), batch shape."""
    T = trainer.train.observed.shape[1]
    cfg = trainer.cfg
    return (tuple(getattr(trainer.model.config, f) for f in ARCHITECTURE_FIELDS), dataclasses.replace(cfg, seed=0),
            min(cfg.n_max, T), min(cfg.m_max, T))


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

    def __len__(self) -> int:
        return len(next(iter(self.params.values())))

    def __call__(self, obs: torch.Tensor, obs_mask: torch.Tensor, query: torch.Tensor):
        """obs (k, B, N, 1+obs_dim), obs_mask (k, B, N), query (k, B, M, 1+dq) -> mean, std (k, B, d, M, dy), gate (k, B, d)."""
        r = self.encode(obs, obs_mask)  # (k, B, H)
        logits = StackedLinear.apply(r, self.params["gate.weight"], self.params["gate.bias"])  # (k, B, d)
        mean, std = self.decode(r, query)
        return mean, std, torch.softmax(logits, dim=-1)

    def encode(self, obs: torch.Tensor, obs_mask: torch.Tensor) -> torch.Tensor:
        """CNEP.encode for k models: masked mean of the encodings, (k, B, N, 1+obs_dim) -> (k, B, H)."""
        k, B, N, _ = obs.shape
        w = obs_mask.to(obs.dtype).unsqueeze(-1)  # (k, B, N, 1)
        x = self.base.embed_time(obs).view(k, B * N, -1)  # (k, B*N, in)
        for j, i in enumerate(self.encoder_layers):
            if j:
                x = F.relu(x)
            x = StackedLinear.apply(x, self.params[f"encoder.{i}.weight"], self.params[f"encoder.{i}.bias"])  # (k, B*N, out)
        enc = x.view(k, B, N, -1) * w  # (k, B, N, H); padded rows contribute exactly 0
        return enc.sum(2) / w.sum(2).clamp_min(1.0)  # (k, B, H)

    def decode(self, r: torch.Tensor, query: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """CNEP.decode (models.cnep.Experts) for k models: r (k, B, H), query (k, B, M, dq) -> mean, std (k, B, d, M, dy)."""
        k, B, M, _ = query.shape
        d, dy = self.base.n_experts, self.base.config.layout.out_dim
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

    `run()` leaves each Trainer as its own `run()` would: history, best state, final weights in its model.
    Not resumable (no state_dict): the evaluation and the demo train start to end.
    """

    def __init__(self, trainers: Sequence[Trainer]) -> None:
        keys = {batch_key(t) for t in trainers}
        if len(keys) != 1 or any(t.step for t in trainers):
            raise ConfigError("BatchedTrainer needs fresh trainers of one network shape, schedule and batch shape "
                              f"(models.batched.batch_key); got {len(keys)} different key(s) over {len(trainers)} trainers.")
        self.trainers = list(trainers)
        self.cfg = trainers[0].cfg
        self.net = StackedCNEP([t.model for t in trainers])
        # Per model: its slice of every stacked parameter (a view: updating it updates the stack) and its own
        # Adam over them, built like the Trainer's. One Adam over the stacks would process a model's elements
        # at other offsets of its vectorised loop than alone, where the last bits can differ.
        self.views = [[self.net.params[n][i].detach() for n in self.net.names] for i in range(len(trainers))]
        gate = [n.startswith("gate.") for n in self.net.names]
        self.optimizers = [make_optimizer([v for v, g in zip(views, gate) if not g], [v for v, g in zip(views, gate) if g],
                                          self.cfg) for views in self.views]
        self.step = 0

    def train_step(self) -> list[dict[str, float]]:
        """One optimiser step of every model; returns each model's loss terms (as `Trainer.train_step`)."""
        batches = [t.next_batch() for t in self.trainers]  # each from its own generator
        stacked = {f: torch.stack([getattr(b, f) for b in batches]) for f in ("obs", "obs_mask", "query")}
        mean, std, gate = self.net(stacked["obs"], stacked["obs_mask"], stacked["query"])  # (k, B, d, M, dy), (k, B, d)
        losses, terms = [], []
        for i, (batch, trainer) in enumerate(zip(batches, self.trainers)):
            loss, term = cnep_loss(mean[i], std[i], gate[i], batch.target, batch.target_mask, trainer.model.config,
                                   self.step / self.cfg.steps)
            term["usage"] = gate[i].detach().mean(0).tolist()
            losses.append(loss)
            terms.append(term)
        params = self.net.params
        for p in params.values():
            if p.grad is not None:
                p.grad.zero_()
        torch.stack(losses).sum().backward()  # d(sum)/d(loss_i) = 1: each model gets exactly its own gradient
        if self.step < self.trainers[0].freeze_steps:  # Adam moments stay 0, so the gates do not move
            for name in ("gate.weight", "gate.bias"):
                params[name].grad.zero_()
        for i, (views, optimizer) in enumerate(zip(self.views, self.optimizers)):
            for name, view in zip(self.net.names, views):
                view.grad = params[name].grad[i]
            torch.nn.utils.clip_grad_norm_(views, self.cfg.grad_clip)  # each model by its own norm
            set_learning_rate(optimizer, self.step, self.cfg)
            optimizer.step()
        self.step += 1
        return terms

    def run(self) -> None:
        """Train every model to the end of the schedule, validating and stopping each as its own Trainer would."""
        active = list(range(len(self.trainers)))
        while self.step < self.cfg.steps and active:
            terms = self.train_step()
            for i in active:
                self.trainers[i].step = self.step
            if self.trainers[active[0]].validation_due():
                for i in active:
                    self.net.copy_to(i, self.trainers[i].model)
            active = [i for i in active if not self.trainers[i].after_step(terms[i])]
        for i in active:  # stopped models already hold the weights of their last validation
            self.net.copy_to(i, self.trainers[i].model)


@dataclass(frozen=True)
class FitRun:
    """The arguments of one `models.fit` call."""

    trajectories: Sequence[np.ndarray]
    config: CNEPConfig
    train_config: TrainConfig = TrainConfig()
    val_trajectories: Sequence[np.ndarray] | None = None


def fit_many(runs: Sequence[FitRun], max_models: int = MAX_MODELS) -> list[tuple[CNEP, list[dict]]]:
    """`models.fit` for each run (no progress bar), runs of one `batch_key` trained together, up to `max_models` at once.

    Returns, in order, what `fit` returns for each run: the best model and its history.
    """
    prepared = [prepare_fit(r.trajectories, r.config, r.train_config, r.val_trajectories) for r in runs]
    groups: dict[tuple, list[Trainer]] = {}
    for trainer, _ in prepared:
        groups.setdefault(batch_key(trainer), []).append(trainer)
    for trainers in groups.values():
        for start in range(0, len(trainers), max_models):
            chunk = trainers[start:start + max_models]
            if len(chunk) == 1:
                chunk[0].run(progress=False)
            else:
                BatchedTrainer(chunk).run()
    return [finish_fit(trainer, split) for trainer, split in prepared]
