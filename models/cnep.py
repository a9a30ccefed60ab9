"""Conditional Neural Expert Processes (CNEP): an encoder, a gate and d expert decoders.

Shapes (B batch, N observations, M queries, d experts, H latent, dy predicted columns):
    obs       (B, N, 1 + obs_dim)    [t, observed columns], t in [0, 1]
    obs_mask  (B, N) bool            True where an observation is real (padding never counts)
    query     (B, M, 1 + query_dim)  [t, query columns]
    mean, std (B, d, M, dy)
    gate      (B, d)                 softmax over experts
All experts run as one batched matrix product (stacked weights), never a Python loop over experts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from models.config import CNEPConfig, span_indices
from models.errors import ConfigError
from models.normaliser import Normaliser


def mlp(widths: list[int]) -> nn.Sequential:
    """Linear layers with ReLU between them and a linear last layer."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class BatchedMLP(nn.Module):
    """`d` independent MLPs with the same widths, evaluated together with `torch.baddbmm`."""

    def __init__(self, d: int, widths: list[int]) -> None:
        super().__init__()
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for a, b in zip(widths[:-1], widths[1:]):
            bound = 1 / math.sqrt(a)  # the same range as nn.Linear's default initialisation
            self.weights.append(nn.Parameter(torch.empty(d, a, b).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(torch.empty(d, 1, b).uniform_(-bound, bound)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (d, R, in) -> (d, R, out)."""
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases)):
            x = torch.baddbmm(b, x, w)  # (d, R, width)
            if i < last:
                x = F.relu(x)
        return x


@dataclass
class Prediction:
    """What `CNEP.generate` returns, in the data's own units (numpy).

    mean, std: (M, dy) of the chosen expert (winner-take-all) or the gate-weighted mixture (MoE);
    expert_means, expert_stds: (d, M, dy); gate: (d,); expert: index of the most probable expert.
    """

    mean: np.ndarray
    std: np.ndarray
    gate: np.ndarray
    expert: int
    expert_means: np.ndarray
    expert_stds: np.ndarray


class CNEP(nn.Module):
    def __init__(self, config: CNEPConfig) -> None:
        super().__init__()
        self.config = config
        lay = config.layout
        self.normaliser = Normaliser(lay.width)
        for name, spans in (("obs_columns", lay.observed), ("query_columns", lay.query), ("out_columns", lay.predicted)):
            self.register_buffer(name, torch.tensor(span_indices(spans), dtype=torch.long), persistent=False)
        H, dy = config.latent_dim, lay.out_dim
        self.encoder = mlp([1 + lay.obs_dim, *config.encoder_widths])
        self.gate = nn.Linear(H, config.n_experts)
        self.experts = BatchedMLP(config.n_experts, [H + 1 + lay.query_dim, *config.expert_widths, 2 * dy])

    @property
    def n_experts(self) -> int:
        return self.config.n_experts

    def encode(self, obs: torch.Tensor, obs_mask: torch.Tensor) -> torch.Tensor:
        """Masked mean of the observation encodings: (B, N, 1+obs_dim), (B, N) -> (B, H)."""
        w = obs_mask.to(obs.dtype).unsqueeze(-1)  # (B, N, 1)
        enc = self.encoder(obs) * w  # (B, N, H); padded rows contribute exactly 0
        return enc.sum(1) / w.sum(1).clamp_min(1.0)  # (B, H)

    def decode(self, r: torch.Tensor, query: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """All experts at once: r (B, H), query (B, M, dq) -> mean, std (B, d, M, dy)."""
        B, M, _ = query.shape
        d, dy = self.n_experts, self.config.layout.out_dim
        x = torch.cat([r.unsqueeze(1).expand(B, M, -1), query], dim=-1)  # (B, M, H + dq)
        out = self.experts(x.reshape(1, B * M, -1).expand(d, -1, -1))  # (d, B*M, 2dy)
        out = out.view(d, B, M, 2 * dy).transpose(0, 1)  # (B, d, M, 2dy)
        mean, raw = out.split(dy, dim=-1)  # (B, d, M, dy) each
        return mean, self.config.min_std + F.softplus(raw)

    def forward(self, obs: torch.Tensor, obs_mask: torch.Tensor, query: torch.Tensor):
        """Normalised inputs -> (mean, std (B, d, M, dy), gate (B, d))."""
        r = self.encode(obs, obs_mask)  # (B, H)
        gate = torch.softmax(self.gate(r), dim=-1)  # (B, d)
        mean, std = self.decode(r, query)
        return mean, std, gate

    @torch.inference_mode()
    def generate(
        self,
        obs_t: np.ndarray,
        obs_values: np.ndarray,
        query_t: np.ndarray,
        query_values: np.ndarray | None = None,
        mixture: bool = False,
    ) -> Prediction:
        """Condition on observations and predict at the query times, in the data's own units.

        obs_t (n,) in [0, 1]; obs_values (n, obs_dim); query_t (m,); query_values (m, query_dim) or
        None when the layout has no query columns. `mixture=False` is winner-take-all (the paper's
        inference), `mixture=True` the gate-weighted mixture of expert means (CNEP-MoE).
        """
        lay = self.config.layout
        obs_values = np.asarray(obs_values, dtype=np.float32).reshape(len(obs_t), lay.obs_dim)
        if query_values is None:
            if lay.query_dim:
                raise ConfigError(f"This model's queries carry {lay.query_dim} columns; pass query_values.")
            query_values = np.zeros((len(query_t), 0), dtype=np.float32)
        query_values = np.asarray(query_values, dtype=np.float32).reshape(len(query_t), lay.query_dim)
        p = next(self.parameters())
        obs = self.prepare(torch.as_tensor(obs_t, dtype=p.dtype), torch.as_tensor(obs_values), self.obs_columns)
        query = self.prepare(torch.as_tensor(query_t, dtype=p.dtype), torch.as_tensor(query_values), self.query_columns)
        mean, std, gate = self(obs[None].to(p.device), torch.ones(1, len(obs_t), dtype=torch.bool, device=p.device), query[None].to(p.device))
        mean, std, gate = mean[0], std[0], gate[0]  # (d, M, dy), (d, M, dy), (d,)
        scale = self.normaliser.scale[self.out_columns]
        means = self.normaliser.denormalise(mean, self.out_columns)  # (d, M, dy)
        stds = std * scale  # (d, M, dy)
        expert = int(gate.argmax())
        if mixture:
            w = gate[:, None, None]  # (d, 1, 1)
            chosen_mean = (w * means).sum(0)  # (M, dy)
            chosen_std = ((w * (stds**2 + means**2)).sum(0) - chosen_mean**2).clamp_min(0).sqrt()
        else:
            chosen_mean, chosen_std = means[expert], stds[expert]
        return Prediction(
            mean=chosen_mean.cpu().numpy(),
            std=chosen_std.cpu().numpy(),
            gate=gate.cpu().numpy(),
            expert=expert,
            expert_means=means.cpu().numpy(),
            expert_stds=stds.cpu().numpy(),
        )

    def prepare(self, t: torch.Tensor, values: torch.Tensor, columns: torch.Tensor) -> torch.Tensor:
        """[t, normalised values]: (..., k) raw -> (..., 1 + k)."""
        values = self.normaliser.normalise(values.to(t.dtype), columns)
        return torch.cat([t.unsqueeze(-1), values], dim=-1)
