"""Online conditioning of a torch CNEP: the runtime's conditioner (runtime.conditioning) over the model.

`OnlineConditioner` steps through an episode of known length `horizon`, as the replay does: step k is at
t = k / (horizon - 1) (the model's training convention), clamped to 1 past the horizon. The conditioning
logic (anchors + window, the running sum of encodings, the gate, the active expert, switches) is
`runtime.Conditioner`'s, shared with the exported policy; `TorchNetwork` hands it the model's encoder and
decoder.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from cnep.models.cnep import CNEP
from cnep.models.errors import ConfigError
from cnep.runtime.conditioning import Columns, Conditioner, ConditioningPolicy, ExpertSwitch

__all__ = [
    "ConditioningPolicy",
    "Decoder",
    "Encoder",
    "ExpertSwitch",
    "OnlineConditioner",
    "OnlineStep",
    "TorchNetwork",
    "model_columns",
]


@dataclass(frozen=True)
class OnlineStep:
    """The result of one control step, in the data's own units.

    gate (d,) sums to 1; expert: the active expert (the policy's rule: the gate's leader, kept unless another
    leads by `switch_margin`); next_mean / next_std (dy,) the active expert's
    prediction at the next step's time;
    switch is set when the active expert changed at this step (never at the first step).
    """

    step: int
    t: float
    gate: np.ndarray
    expert: int
    next_mean: np.ndarray
    next_std: np.ndarray
    switch: ExpertSwitch | None


class Encoder(nn.Module):
    """The model's per-observation encoder: [t, normalised observed columns] (N, 1 + obs_dim) -> (N, H), its
    projection of the observed-only columns (`CNEPConfig.feature_components`) included."""

    def __init__(self, model: CNEP) -> None:
        super().__init__()
        self.model = model

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.model.encoder(self.model.encoder_inputs(obs))  # (N, H)


class Decoder(nn.Module):
    """The gate and every expert on one latent: r (1, H), queries (M, 1 + query_dim) -> gate (d,), mean and std
    (d, M, dy), normalised."""

    def __init__(self, model: CNEP) -> None:
        super().__init__()
        self.model = model

    def forward(self, r: torch.Tensor, query: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        gate = torch.softmax(self.model.gate(r[0]), dim=-1)  # (d,)
        mean, std = self.model.decode(r, query[None])  # (1, d, M, dy) each
        return gate, mean[0], std[0]


class TorchNetwork:
    """A CNEP's `Encoder` and `Decoder` on numpy arrays (runtime.conditioning.Network), in inference mode.

    The same two modules are what `cnep export` writes as ONNX graphs.
    """

    def __init__(self, model: CNEP) -> None:
        self.model = model.eval()
        self.encoder, self.decoder = Encoder(self.model), Decoder(self.model)

    @torch.inference_mode()
    def encode(self, obs: np.ndarray) -> np.ndarray:
        """[t, normalised observed columns] (N, 1 + obs_dim) -> encodings (N, H)."""
        return self.encoder(torch.from_numpy(obs)).numpy()

    @torch.inference_mode()
    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Latent (1, H), queries (M, 1 + query_dim) -> gate (d,), mean and std (d, M, dy), normalised."""
        gate, mean, std = self.decoder(torch.from_numpy(r), torch.from_numpy(query))
        return gate.numpy(), mean.numpy(), std.numpy()


def model_columns(model: CNEP) -> Columns:
    """The model's observed, query and predicted columns with its normaliser's statistics."""
    lay, norm = model.config.columns, model.normaliser
    return Columns(lay.observed, lay.query, lay.predicted, norm.loc.float().numpy(), norm.scale.float().numpy())


class OnlineConditioner:
    """Stateful conditioner for one episode at a time (`reset()` starts a new one).

    `model` is a trained CNEP (eval mode), `horizon` the episode's expected number of steps (>= 2).
    """

    def __init__(self, model: CNEP, horizon: int, policy: ConditioningPolicy = ConditioningPolicy()) -> None:
        if horizon < 2:
            raise ConfigError(f"OnlineConditioner horizon must be >= 2 steps (t = k / (horizon - 1)), got {horizon}.")
        self.model = model.eval()
        self.horizon = horizon
        self.policy = policy
        self.conditioner = Conditioner(TorchNetwork(model), model_columns(model), policy)
        self.width = self.conditioner.width

    def reset(self, seed: int | None = None) -> None:
        """Forget the conditioning set: the next `step` is step 0 of a new episode (seed: its draws, as
        `runtime.Conditioner.reset` takes it)."""
        self.conditioner.reset(seed)

    @property
    def k(self) -> int:
        """Index of the next step."""
        return self.conditioner.k

    @property
    def gate(self) -> np.ndarray | None:
        return self.conditioner.gate

    @property
    def expert(self) -> int | None:
        return self.conditioner.expert

    def time_of(self, k: int | np.ndarray) -> np.ndarray:
        """Normalised time of step(s) k: k / (horizon - 1), clamped to [0, 1]."""
        return np.clip(np.asarray(k, dtype=np.float64) / (self.horizon - 1), 0.0, 1.0)

    @property
    def n_conditioning(self) -> int:
        """Number of observations in the current conditioning set."""
        return self.conditioner.n_conditioning

    def step(self, row: np.ndarray, timestamp_ns: int | None = None) -> OnlineStep:
        """Take the observation at the next step (a `(width,)` trajectory row) and re-evaluate the gate."""
        row = np.asarray(row, dtype=np.float32)
        if row.shape != (self.width,):
            raise ConfigError(
                f"An online observation must be a ({self.width},) row of the model's columns, got shape {row.shape}."
            )
        k = self.k
        t = float(self.time_of(k))
        gate, expert, switch, mean, std = self.conditioner.step(row, t, self.time_of([k + 1]), timestamp_ns)
        return OnlineStep(k, t, gate, expert, mean[0], std[0], switch)

    def predict(self, query_t: np.ndarray, all_experts: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Predict at normalised times `query_t` (m,) from the current set, in the data's units.

        Returns mean, std (m, dy) of the active expert (winner-take-all, the paper's inference); with
        `all_experts=True`, (d, m, dy) for every expert.
        """
        if self.conditioner.n_conditioning == 0:
            raise ConfigError("OnlineConditioner.predict needs at least one observation: call step() first.")
        return self.conditioner.predict(query_t, all_experts)
