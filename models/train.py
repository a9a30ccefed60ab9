"""Training CNEP on a list of trajectories: seeded, vectorised batches, best-model keeping.

The optimiser recipe for a CPU budget of minutes (docs/concepts.md): Adam, a linear
learning-rate warm-up then cosine decay, and the gate held uniform (zero-initialised, not updated) for
the first `gate_freeze_fraction` of the steps, so that the experts learn to reconstruct before the
gate starts to commit, and then learning at `gate_lr_scale` times the learning rate (by default the
assignment's own: `models.assignments`). The best model by validation error is kept, from the step where the
assignment's posterior has settled on (`Assignment.settled_fraction`); with `keep_candidates`, also the best of
each part of training (models.candidates), for a choice made after it in closed loop. Steps, warm-up and validation
interval left unset are the training schedule's for the trajectories it trains on (models.schedule).

Adam runs fused (one kernel over all parameters, faster than the per-tensor `foreach` path for a network this
small: benchmarks/bench_training.py). `models.batched` trains several
such runs in one computation through the same helpers (`make_optimizer`, `set_learning_rate`, `next_batch`,
`decay_observed_only`, `after_step`), so each of its models matches a run of this Trainer bit for bit.
"""

from __future__ import annotations

import copy
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from cnep.models.candidates import Candidates
from cnep.models.cnep import CNEP
from cnep.models.config import CNEPConfig, ConditioningPolicy, TrainConfig
from cnep.models.errors import ConfigError
from cnep.models.loss import cnep_loss, expert_nll
from cnep.models.normaliser import Moments
from cnep.models.projection import principal_projection
from cnep.models.sampler import Batch, TrajectoryStack, sample_batch
from cnep.models.schedule import scheduled, with_components
from cnep.models.split import split_if_idle, split_steps
from cnep.models.threads import torch_threads

log = logging.getLogger(__name__)

VAL_BATCHES = 8  # fixed validation batches, drawn once
# A validation error (mean squared, normalised units) above this means training diverged: predicting the training
# mean scores about 1 there, and an untrained network a few units.
DIVERGED_ERROR = 1e3
# A run learned something when its best validation error is below this share of what predicting the training mean
# scores; within it, the model does no better than a constant (Trainer.not_learned).
LEARNED_RATIO = 0.95
VAL_BATCH_SIZE = 64
# The dropout masks (`TrainConfig.observed_only_dropout`) come from a generator of their own, seeded with the run's
# seed plus this: the batches are the same with and without them.
DROPOUT_SEED_OFFSET = 780
# `fit` without validation trajectories holds VAL_FRACTION of them out, but only from this many on:
# below it a held-out fifth would take whole behaviours away (two Baxter demonstrations would train on one).
MIN_TRAJECTORIES_TO_HOLD_OUT = 10
VAL_FRACTION = 0.2


def build_model(config: CNEPConfig, train: Sequence[np.ndarray] | Moments, seed: int) -> CNEP:
    """A freshly initialised model (seeded) whose normaliser (and with `feature_components`, its projection:
    models.projection) is fitted on `train`: (T_i, width) trajectories, or their `Moments` (with the scatter matrix
    of `config.columns.observed_only` where the model projects them)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        model = CNEP(config)
    with torch.no_grad():  # the gate starts uniform: zero weights, zero bias
        model.gate.weight.zero_()
        model.gate.bias.zero_()
    co = config.projected_columns
    moments = train if isinstance(train, Moments) else Moments.total(Moments.of(t, co) for t in train)
    model.normaliser.fit_moments(moments)
    if co:
        if moments.co != co:
            raise ConfigError(
                f"feature_components needs the moments' scatter matrix of the {len(co)} columns the model observes but "
                f"does not predict (Moments.of(rows, co)); these carry it for {len(moments.co)} columns."
            )
        scale = model.normaliser.scale.double().numpy()[list(co)]
        projection = principal_projection(moments, scale, config.feature_components)
        model.feature_projection.copy_(torch.from_numpy(projection))
    return model


def split_validation(trajectories: Sequence[np.ndarray], fraction: float, seed: int):
    """Split by whole trajectory (never by time step): (train, validation)."""
    n = len(trajectories)
    n_val = max(1, round(n * fraction)) if n >= 2 else 0
    if n_val == 0:
        raise ConfigError(f"Need at least 2 trajectories to hold one out for validation, got {n}.")
    order = np.random.default_rng(seed).permutation(n)
    val = set(order[:n_val].tolist())
    return [t for i, t in enumerate(trajectories) if i not in val], [t for i, t in enumerate(trajectories) if i in val]


def lr_factor(step: int, cfg: TrainConfig) -> float:
    """Linear warm-up to 1, then cosine decay to 0.05 at the last step."""
    if step < cfg.warmup_steps:
        return (step + 1) / cfg.warmup_steps
    progress = (step - cfg.warmup_steps) / max(1, cfg.steps - cfg.warmup_steps)
    return 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))


def make_optimizer(groups: Sequence[tuple[list[torch.Tensor], float]], lr: float) -> torch.optim.Adam:
    """Adam over (parameters, `lr_scale`) groups (the network at 1, the gate at its gate_lr_scale), fused into one
    kernel."""
    return torch.optim.Adam([{"params": params, "lr_scale": scale} for params, scale in groups], lr=lr, fused=True)


def set_learning_rate(optimizer: torch.optim.Optimizer, step: int, cfg: TrainConfig) -> None:
    """The schedule's learning rate at `step`, times each parameter group's `lr_scale`."""
    for group in optimizer.param_groups:
        group["lr"] = cfg.lr * lr_factor(step, cfg) * group["lr_scale"]


def dropout_keep(obs: torch.Tensor, spans: Sequence[tuple[int, int]], share: float, g: torch.Generator) -> torch.Tensor:
    """`TrainConfig.observed_only_dropout` of a batch's contexts (B, n, 1 + obs_dim): multipliers (B, n, width of
    `spans`) of the encoder's inputs on `spans` (`CNEP.observed_only_inputs`), each 0 with probability `share`, else
    1 / (1 - share); the model applies them (`CNEP.encoder_inputs`)."""
    width = sum(b - a for a, b in spans)
    return (torch.rand((*obs.shape[:-1], width), generator=g) >= share).float() / (1 - share)


@torch.no_grad()
def decay_observed_only(
    weight: torch.Tensor, spans: Sequence[tuple[int, int]], optimizer: torch.optim.Optimizer, decay: float
) -> None:
    """`TrainConfig.observed_only_decay` after an optimiser step: the encoder's first-layer weight (..., width,
    inputs) on the input `spans` (`CNEP.observed_only_inputs`) shrinks in place by the network's learning rate of the
    step (`optimizer`'s first group) times `decay`."""
    factor = 1.0 - optimizer.param_groups[0]["lr"] * decay
    for a, b in spans:
        weight[..., a:b].mul_(factor)


@torch.no_grad()
def demonstration_nll(
    model, r: torch.Tensor, demonstration: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor]:
    """What the EM assignments' responsibilities are computed from (models.loss): each expert's mean NLL (..., B, d)
    of the demonstration each sample was drawn from, predicted from the sample's context, and that demonstration's
    number of values (..., B). model: a CNEP (or k stacked: models.batched, leading dimension k); r: the latent
    (..., B, H) of the batch's contexts, as the training step's forward pass returns it (`latent=True`; not
    differentiated here); demonstration: (query, target, mask) of `TrajectoryStack.demonstration`, on r's device."""
    query, target, mask = demonstration
    mean, std = model.decode(r, query)  # (..., B, d, P, dy)
    nll = expert_nll(mean, std, target, mask)  # (..., B, d)
    return nll, mask.sum(-1).to(mean.dtype) * mean.shape[-1]


@torch.no_grad()
def wta_error(model: CNEP, batch: Batch) -> float:
    """Mean squared error (normalised units) of the most probable expert's mean on the targets."""
    mean, _, gate = model(batch.obs, batch.obs_mask, batch.query)  # (B, d, M, dy), (B, d)
    chosen = mean[torch.arange(len(gate)), gate.argmax(-1)]  # (B, M, dy)
    w = batch.target_mask.unsqueeze(-1).to(chosen.dtype)  # (B, M, 1)
    return float(((chosen - batch.target) ** 2 * w).sum() / (w.sum() * chosen.shape[-1]))


@torch.no_grad()
def mean_prediction_error(batch: Batch) -> float:
    """Mean squared error (normalised units) of predicting the training mean on the targets: the normaliser's `loc`
    is the training rows' mean, so that prediction is 0. The error a model that learned nothing stays at."""
    w = batch.target_mask.unsqueeze(-1).to(batch.target.dtype)  # (B, M, 1)
    return float((batch.target**2 * w).sum() / (w.sum() * batch.target.shape[-1]))


@dataclass
class Trainer:
    """One training run; `state_dict` / `load_state_dict` make it resumable step for step."""

    model: CNEP
    train: TrajectoryStack
    val: TrajectoryStack
    cfg: TrainConfig
    step: int = 0
    best_error: float = math.inf
    best_state: dict = field(default_factory=dict)
    best_step: int = 0
    history: list[dict] = field(default_factory=list)
    diverged: str | None = None  # why training stopped on a validation error that is not finite or far too large
    # candidates kept besides the best weights (models.candidates): the best of each of this many parts of training
    keep_candidates: int = 0
    # how the deployed policy conditions the model: the shape of the online contexts (TrainConfig.online_contexts)
    conditioning: ConditioningPolicy = field(default_factory=ConditioningPolicy)

    def __post_init__(self) -> None:
        self.cfg = scheduled(
            self.cfg.for_assignment(self.model.config.assigned), len(self.train), model=self.model.config
        )
        gate = {id(p) for p in self.model.gate.parameters()}
        self.optimizer = make_optimizer(
            [
                ([p for p in self.model.parameters() if id(p) not in gate], 1.0),
                (list(self.model.gate.parameters()), self.cfg.gate_lr_scale),
            ],
            self.cfg.lr,
        )
        self.generator = torch.Generator().manual_seed(self.cfg.seed)
        self.dropout_generator = torch.Generator().manual_seed(self.cfg.seed + DROPOUT_SEED_OFFSET)
        self.dropped = self.model.observed_only_inputs() if self.cfg.observed_only_dropout else []
        val_gen = torch.Generator().manual_seed(self.cfg.seed + 1)
        self.val_batches = [
            sample_batch(
                self.val,
                VAL_BATCH_SIZE,
                self.cfg.n_max,
                self.cfg.m_max,
                val_gen,
                first_steps=self.first_steps,
                online=self.online,
            )
            for _ in range(VAL_BATCHES)
        ]
        self.mean_error = float(np.mean([mean_prediction_error(b) for b in self.val_batches]))
        self.freeze_steps = int(self.cfg.gate_freeze_fraction * self.cfg.steps)
        self.decayed = self.model.observed_only_inputs() if self.cfg.observed_only_decay else []
        if self.decayed and self.cfg.observed_only_decay * self.cfg.lr >= 1:  # would flip those weights' signs
            raise ConfigError(
                f"observed_only_decay x lr must be below 1 (the share of the observed-only weights taken off per "
                f"step), got {self.cfg.observed_only_decay} x {self.cfg.lr}; lower lr or observed_only_decay (0 "
                f"turns it off)"
            )
        assignment = self.model.config.assigned
        # validations before this step are logged but never kept as the best model (Assignment.settled_fraction)
        self.keep_from = int(assignment.settled_fraction * self.cfg.steps)
        self.candidates = (
            Candidates(self.keep_candidates, self.keep_from, self.cfg.steps) if self.keep_candidates else None
        )
        balanced = assignment.balancing is not None and self.model.n_experts > 1
        # the steps at which an idle expert may take a copy of a busy one (models.split)
        self.split_at = (
            split_steps(self.cfg.steps, self.freeze_steps, assignment.balancing.fade_from) if balanced else frozenset()
        )

    @property
    def first_steps(self) -> tuple[float, int]:
        """The sampler's share of first-steps contexts and their most steps (`TrainConfig.first_steps_*`)."""
        return self.cfg.first_steps_fraction, self.cfg.first_steps_max

    @property
    def online(self) -> tuple[float, int, int]:
        """The sampler's share of online contexts and their shape (`TrainConfig.online_contexts`, `conditioning`)."""
        return self.cfg.online_contexts, self.conditioning.window, self.conditioning.anchors

    @property
    def device(self) -> torch.device:
        """Where the model's parameters are: batches are drawn on the CPU (seeded) and moved there."""
        return next(self.model.parameters()).device

    def next_batch(self) -> Batch:
        """The next training batch from this run's generators, on the model's device."""
        batch = sample_batch(
            self.train,
            self.cfg.batch_size,
            self.cfg.n_max,
            self.cfg.m_max,
            self.generator,
            self.cfg.obs_noise,
            self.first_steps,
            self.online,
        )
        if self.dropped:
            batch.keep = dropout_keep(batch.obs, self.dropped, self.cfg.observed_only_dropout, self.dropout_generator)
        return batch.to(self.device)

    def demonstration(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(query, target, mask) of the demonstration each sample of `batch` was drawn from, on the model's device."""
        return tuple(x.to(self.device) for x in self.train.demonstration(batch.trajectory.cpu()))

    def split_idle(self, params: dict[str, torch.Tensor], state: dict[str, dict]) -> None:
        """`models.split.split_if_idle` on this model: params, its parameters by name (views of a stack in
        models.batched, holding the same values as `self.model`); state, their Adam state by name."""
        done = split_if_idle(self.model, self.train, params, state, self.cfg.seed, self.step)
        if done is not None:
            idle, busy, counts = done
            log.info(
                "step %d: expert %d is hardly used (training demonstrations the gate gives each expert: %s); it "
                "restarts as a copy of expert %d, the most used, so that the two can share that expert's "
                "demonstrations",
                self.step,
                idle,
                counts,
                busy,
            )

    def train_step(self) -> dict[str, float]:
        if self.step in self.split_at:
            params = dict(self.model.named_parameters())
            self.split_idle(params, {name: self.optimizer.state.get(p, {}) for name, p in params.items()})
        batch = self.next_batch()
        set_learning_rate(self.optimizer, self.step, self.cfg)
        mean, std, gate, r = self.model(batch.obs, batch.obs_mask, batch.query, latent=True, keep=batch.keep)
        posterior = (
            demonstration_nll(self.model, r, self.demonstration(batch))
            if self.model.config.assigned.uses_demonstration
            else None
        )
        progress = self.step / self.cfg.steps
        loss, terms = cnep_loss(
            mean, std, gate, batch.target, batch.target_mask, self.model.config, progress, posterior, self.cfg.nll_beta
        )
        self.optimizer.zero_grad(set_to_none=False)
        loss.backward()
        if self.step < self.freeze_steps:  # Adam moments stay 0, so the gate does not move
            for p in self.model.gate.parameters():
                if p.grad is not None:
                    p.grad.zero_()
        torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.cfg.grad_clip)
        self.optimizer.step()
        decay_observed_only(self.model.encoder[0].weight, self.decayed, self.optimizer, self.cfg.observed_only_decay)
        self.step += 1
        terms["usage"] = gate.detach().mean(0).tolist()
        return terms

    def validation_error(self) -> float:
        """The winner-take-all error over the fixed validation batches (normalised units)."""
        self.model.eval()
        error = float(np.mean([wta_error(self.model, b.to(self.device)) for b in self.val_batches]))
        self.model.train()
        return error

    def validate(self) -> float:
        """`validation_error`, keeping the weights when it is the best so far (from `keep_from` on), and offering
        them to the candidates (`keep_candidates`)."""
        error = self.validation_error()
        if error <= DIVERGED_ERROR and self.step >= self.keep_from:
            if error < self.best_error:
                self.best_error, self.best_step = error, self.step
                self.best_state = copy.deepcopy(self.model.state_dict())
            if self.candidates is not None:
                self.candidates.offer(self.step, error, self.model.state_dict())
        return error

    def state_dict(self) -> dict:
        return {
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "generator": self.generator.get_state(),
            "dropout_generator": self.dropout_generator.get_state(),
            "step": self.step,
            "best_error": self.best_error,
            "best_state": self.best_state,
            "best_step": self.best_step,
            "history": self.history,
            "diverged": self.diverged,
            "candidates": self.candidates.state_dict() if self.candidates is not None else None,
        }

    def load_state_dict(self, state: dict) -> None:
        self.model.load_state_dict(state["model"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.generator.set_state(state["generator"])
        self.dropout_generator.set_state(state["dropout_generator"])
        self.step, self.best_error = state["step"], state["best_error"]
        self.best_state, self.history = state["best_state"], state["history"]
        self.diverged = state.get("diverged")
        if self.candidates is not None and state.get("candidates") is not None:
            self.candidates.load_state_dict(state["candidates"])
        if "best_step" in state:
            self.best_step = state["best_step"]
        elif self.history:  # saved before best_step was recorded: every validation could be kept then
            self.best_step = min(self.history, key=lambda h: h["val_error"])["step"]

    def run(self, progress: bool = True, until: int | None = None) -> None:
        """Train up to step `until` (default: all steps), validating every `val_every` steps."""
        from tqdm.auto import tqdm

        until = self.cfg.steps if until is None else min(until, self.cfg.steps)
        bar = tqdm(total=until, initial=self.step, disable=not progress, desc="train", unit="step", leave=False)
        while self.step < until:
            terms = self.train_step()
            bar.update(1)
            stop = self.after_step(terms)
            if "val_error" in terms:
                bar.set_postfix(
                    loss=f"{terms['loss']:.3g}",
                    val=f"{terms['val_error']:.3g}",
                    usage="/".join(f"{u:.2f}" for u in terms["usage"]),
                )
            if stop:
                break
        bar.close()

    def not_learned(self) -> str | None:
        """Why the run learned nothing, naming the likely causes and the numbers, when its best validation error is
        no better than predicting the training mean (`mean_error`); None when it is better."""
        if self.best_error < LEARNED_RATIO * self.mean_error:
            return None
        lr, default = self.cfg.lr, TrainConfig.__dataclass_fields__["lr"].default
        if lr > default:
            cause = f"the learning rate, {lr / default:.4g} times the default (lr {lr:g}; the default is {default:g})"
        elif lr < default:
            cause = f"the learning rate, below the default (lr {lr:g}; the default is {default:g}), or too few steps"
        else:
            cause = f"too few steps ({self.step})"
        best = f"{self.best_error:.4g}" if self.best_state else "none kept"
        return (
            f"the model learned nothing: its best validation error ({best}) is no better than predicting the training "
            f"mean ({self.mean_error:.4g}, normalised units; {LEARNED_RATIO:g} of it is the bar); likely cause: "
            f"{cause}; else the data: what the model predicts may not follow from what it observes (its layout, "
            f"its recordings)"
        )

    def validation_due(self) -> bool:
        """Whether the step just taken is a validation step (every `val_every` steps and the last one)."""
        return self.step % self.cfg.val_every == 0 or self.step == self.cfg.steps

    def after_step(self, terms: dict) -> bool:
        """Validate and record `terms` when due; True when training should stop early."""
        if not self.validation_due():
            return False
        terms.update(step=self.step, val_error=self.validate())
        self.history.append(terms)
        log.debug("step %d %s", self.step, terms)
        if not (
            math.isfinite(terms["val_error"]) and terms["val_error"] <= DIVERGED_ERROR and math.isfinite(terms["loss"])
        ):
            self.diverged = (
                f"at step {self.step} the training loss is {terms['loss']:.3g} and the validation error "
                f"{terms['val_error']:.3g} (normalised units, where predicting the training mean scores about 1)"
            )
            log.info("stopped at step %d: training diverged", self.step)
            return True
        if self.should_stop():
            log.info("early stop at step %d: no improvement in %d validations", self.step, self.cfg.patience)
            return True
        return False

    def should_stop(self) -> bool:
        if self.diverged is not None:
            return True
        p = self.cfg.patience
        if p is None or len(self.history) <= p:
            return False
        return min(h["val_error"] for h in self.history[-p:]) > self.best_error


def fit(
    trajectories: Sequence[np.ndarray],
    config: CNEPConfig,
    train_config: TrainConfig = TrainConfig(),
    val_trajectories: Sequence[np.ndarray] | None = None,
    progress: bool = True,
    conditioning: ConditioningPolicy = ConditioningPolicy(),
) -> tuple[CNEP, list[dict]]:
    """Train a CNEP on `(T_i, width)` trajectories; returns the best model (by validation) and the history.

    Without `val_trajectories`, VAL_FRACTION of the trajectories (whole trajectories, seeded) are held
    out for validation when there are at least MIN_TRAJECTORIES_TO_HOLD_OUT; with fewer, every
    trajectory trains and validation uses the training set (logged as a warning). Each history record
    says which: `n_train`, `n_val` and `validation` ("given", "held out" or "training set").
    `models.batched.fit_many` trains several such runs together, each with this function's result.
    Runs on `train_config.threads` torch threads (one by default: models.threads), restored afterwards.
    `conditioning`: how the deployed policy will condition the model (the shape of `TrainConfig.online_contexts`).
    """
    with torch_threads(train_config.threads):
        trainer, split = prepare_fit(trajectories, config, train_config, val_trajectories, conditioning)
        trainer.run(progress=progress)
        return finish_fit(trainer, split)


def prepare_fit(
    trajectories: Sequence[np.ndarray],
    config: CNEPConfig,
    train_config: TrainConfig,
    val_trajectories: Sequence[np.ndarray] | None = None,
    conditioning: ConditioningPolicy = ConditioningPolicy(),
) -> tuple[Trainer, dict]:
    """`fit` up to training: the checked data, the seeded model and its Trainer, and the split's description."""
    train, val, validation = _validation_split(list(trajectories), val_trajectories, train_config.seed)
    for t in train + val:
        if np.ndim(t) != 2 or np.shape(t)[1] != config.columns.width:
            raise ConfigError(f"Trajectories must be (T, {config.columns.width}) arrays, got shape {np.shape(t)}.")
    model = build_model(with_components(config, len(train)), train, train_config.seed)
    trainer = Trainer(
        model, TrajectoryStack(train, model), TrajectoryStack(val, model), train_config, conditioning=conditioning
    )
    return trainer, {"n_train": len(train), "n_val": len(val), "validation": validation}


def finish_fit(trainer: Trainer, split: dict) -> tuple[CNEP, list[dict]]:
    """`fit`'s result from a trained Trainer: its best model in eval mode and the history with the split."""
    model = trainer.model
    if not trainer.best_state:
        raise ConfigError(
            f"Training diverged before any validation could be kept ({trainer.diverged}); lower the learning rate "
            f"(lr {trainer.cfg.lr}), or look for values far outside the others in the trajectories."
        )
    if (why := trainer.not_learned()) is not None:
        log.warning("fit: %s", why)
    model.load_state_dict(trainer.best_state)
    model.eval()
    return model, [{**record, **split} for record in trainer.history]


def _validation_split(
    trajectories: list[np.ndarray], val_trajectories: Sequence[np.ndarray] | None, seed: int
) -> tuple[list[np.ndarray], list[np.ndarray], str]:
    """(train, validation, which validation) for `fit`; never drops a trajectory silently."""
    if val_trajectories:
        return trajectories, list(val_trajectories), "given"
    n = len(trajectories)
    if n >= MIN_TRAJECTORIES_TO_HOLD_OUT:
        train, val = split_validation(trajectories, VAL_FRACTION, seed)
        log.info(
            "fit: validating on %d of the %d trajectories, held out of training (pass val_trajectories "
            "to train on all of them)",
            len(val),
            n,
        )
        return train, val, "held out"
    log.warning(
        "fit: only %d trajectories (fewer than %d), so all of them train and validation uses the training "
        "set; pass val_trajectories to validate on others",
        n,
        MIN_TRAJECTORIES_TO_HOLD_OUT,
    )
    return trajectories, trajectories, "training set"
