"""Online conditioning: re-evaluate the gate at every control step from a sliding conditioning set.

The paper's "online conditioning and on-the-fly adaptation": at each step the current observation
(a trajectory row: features, pose, gripper at time t) enters the conditioning set, the gate is
re-evaluated, and the active expert may switch. The authors' code has no such mode; this is ours.

Conditioning policy (`ConditioningPolicy`): the set at step k is
    the first `anchors` observations of the episode (kept for the whole episode: the start point by
    default, which fixes where the movement began) + the latest `window` observations after them.
The encoder's latent is a masked mean of per-observation encodings, so the conditioner keeps a
running sum of the encodings in the set: one encoder row per step is added, the one leaving the
window is subtracted. A step costs O(1) (one encoder row, the gate, one query per expert), whatever
the episode's length.

Time: step k of an episode of `horizon` steps is at t = k / (horizon - 1) (the model's training
convention), clamped to 1 past the horizon. Query columns (if the model has any) of the predicted
future steps are held at the current row's values, since future observations are unknown.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import torch

from cnep.models.cnep import CNEP
from cnep.models.config import ConditioningPolicy
from cnep.models.errors import ConfigError


@dataclass(frozen=True)
class ExpertSwitch:
    """The active expert changed at `step`: `from_expert` -> `to_expert`, with the new gate (d,)."""

    step: int
    t: float  # normalised time in [0, 1]
    timestamp_ns: int | None
    from_expert: int
    to_expert: int
    gate: np.ndarray


@dataclass(frozen=True)
class OnlineStep:
    """The result of one control step, in the data's own units.

    gate (d,) sums to 1; expert = argmax of the gate; next_mean / next_std (dy,) the active expert's
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
        lay = model.config.columns
        self.width = lay.width
        norm = model.normaliser
        # Per-column normalisation of the inputs and outputs, gathered once (not per step).
        self._obs_cols = model.obs_columns.numpy()
        self._query_cols = model.query_columns.numpy()
        self._obs_loc, self._obs_scale = norm.loc[model.obs_columns].float(), norm.scale[model.obs_columns].float()
        self._q_loc, self._q_scale = norm.loc[model.query_columns].float(), norm.scale[model.query_columns].float()
        self._out_loc, self._out_scale = norm.loc[model.out_columns].float(), norm.scale[model.out_columns].float()
        self.reset()

    def reset(self) -> None:
        """Forget the conditioning set: the next `step` is step 0 of a new episode."""
        H = self.model.config.latent_dim
        self.k = 0  # index of the next step
        self._sum = torch.zeros(H, dtype=torch.float64)  # running sum of the encodings in the set
        self._n = 0  # observations in the set
        self._window: deque[torch.Tensor] = deque()  # encodings (H,) of the sliding part, oldest first
        self._r: torch.Tensor | None = None  # latent (H,) of the current set
        self._query = torch.zeros(0)  # current row's normalised query columns (query_dim,)
        self.gate: np.ndarray | None = None
        self.expert: int | None = None

    def time_of(self, k: int | np.ndarray) -> np.ndarray:
        """Normalised time of step(s) k: k / (horizon - 1), clamped to [0, 1]."""
        return np.clip(np.asarray(k, dtype=np.float64) / (self.horizon - 1), 0.0, 1.0)

    @property
    def n_conditioning(self) -> int:
        """Number of observations in the current conditioning set."""
        return self._n

    @torch.inference_mode()
    def step(self, row: np.ndarray, timestamp_ns: int | None = None) -> OnlineStep:
        """Take the observation at the next step (a `(width,)` trajectory row) and re-evaluate the gate."""
        row = np.asarray(row, dtype=np.float32)
        if row.shape != (self.width,):
            raise ConfigError(
                f"An online observation must be a ({self.width},) row of the model's columns, got shape {row.shape}."
            )
        k, t = self.k, float(self.time_of(self.k))
        x = torch.from_numpy(row)
        obs = (x[self._obs_cols] - self._obs_loc) / self._obs_scale  # (obs_dim,)
        self._query = (x[self._query_cols] - self._q_loc) / self._q_scale  # (query_dim,)
        enc = self.model.encoder(self.model.embed_time(torch.cat([torch.tensor([t]), obs])))  # (H,)
        self._add(k, enc.double())
        self._r = (self._sum / self._n).float()  # (H,) the masked mean over the set
        gate = torch.softmax(self.model.gate(self._r), dim=-1).numpy()  # (d,)
        expert = int(gate.argmax())
        switch = None
        if self.expert is not None and expert != self.expert:
            switch = ExpertSwitch(k, t, timestamp_ns, self.expert, expert, gate)
        self.gate, self.expert = gate, expert
        self.k += 1
        mean, std = self.predict(self.time_of([k + 1]))  # (1, dy) each
        return OnlineStep(k, t, gate, expert, mean[0], std[0], switch)

    def _add(self, k: int, enc: torch.Tensor) -> None:
        """Put the encoding of step k into the set by the policy; evict what leaves the window."""
        self._sum += enc
        self._n += 1
        if k < self.policy.anchors:
            return  # an anchor stays for the whole episode
        self._window.append(enc)
        if len(self._window) > self.policy.window:
            self._sum -= self._window.popleft()
            self._n -= 1

    @torch.inference_mode()
    def predict(self, query_t: np.ndarray, all_experts: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Predict at normalised times `query_t` (m,) from the current set, in the data's units.

        Returns mean, std (m, dy) of the active expert (winner-take-all, the paper's inference); with
        `all_experts=True`, (d, m, dy) for every expert.
        """
        if self._r is None:
            raise ConfigError("OnlineConditioner.predict needs at least one observation: call step() first.")
        qt = torch.as_tensor(np.asarray(query_t), dtype=torch.float32)  # (m,)
        query = torch.cat([qt[:, None], self._query.expand(len(qt), -1)], dim=-1)  # (m, 1 + query_dim)
        mean, std = self.model.decode(self._r[None], query[None])  # (1, d, m, dy) each
        means = mean[0] * self._out_scale + self._out_loc  # (d, m, dy)
        stds = std[0] * self._out_scale  # (d, m, dy)
        if all_experts:
            return means.numpy(), stds.numpy()
        return means[self.expert].numpy(), stds[self.expert].numpy()
