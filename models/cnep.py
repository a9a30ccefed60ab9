"""Conditional Neural Expert Processes (CNEP): an encoder, a gate and d expert decoders.

Shapes (B batch, N observations, M queries, d experts, H latent, dy predicted columns):
    obs       (B, N, 1 + obs_dim)    [t, observed columns], t in [0, 1]
    obs_mask  (B, N) bool            True where an observation is real (padding never counts)
    query     (B, M, 1 + query_dim)  [t, query columns]
    mean, std (B, d, M, dy)
    gate      (B, d)                 softmax over experts
All experts run as one batched matrix product (stacked weights), never a Python loop over experts.
With `feature_components` K, the encoder reads a context's observed-only columns (such as image features) as their
top K principal components over the training rows (`project`, models.projection); the contexts stay as above.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cnep.models.config import CNEPConfig, span_indices
from cnep.models.errors import ConfigError
from cnep.models.normaliser import Normaliser


def mlp(widths: list[int]) -> nn.Sequential:
    """Linear layers with ReLU between them and a linear last layer."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(widths) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class Experts(nn.Module):
    """`d` expert MLPs with the same widths on `[r, query]`, evaluated together.

    The first layer is split into a latent part and a query part: the latent part is computed once
    per sample (not once per query) for all experts in one matrix product; the hidden layers run as
    one `torch.baddbmm` over stacked weights.
    """

    def __init__(self, d: int, latent_dim: int, query_dim: int, widths: list[int]) -> None:
        super().__init__()
        self.d = d
        fan_in = latent_dim + query_dim
        bound = 1 / math.sqrt(fan_in)  # the same range as nn.Linear's default initialisation
        self.first_r = nn.Parameter(torch.empty(latent_dim, d * widths[0]).uniform_(-bound, bound))
        self.first_q = nn.Parameter(torch.empty(query_dim, d * widths[0]).uniform_(-bound, bound))
        self.first_b = nn.Parameter(torch.empty(d * widths[0]).uniform_(-bound, bound))
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for a, b in zip(widths[:-1], widths[1:]):
            bound = 1 / math.sqrt(a)
            self.weights.append(nn.Parameter(torch.empty(d, a, b).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(torch.empty(d, 1, b).uniform_(-bound, bound)))

    def forward(self, r: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
        """r (B, H), query (B, M, dq) -> (d, B*M, out)."""
        B, M, _ = query.shape
        h = (r @ self.first_r + self.first_b).unsqueeze(1) + query @ self.first_q  # (B, M, d*w0)
        x = h.view(B * M, self.d, -1).transpose(0, 1)  # (d, B*M, w0)
        for w, b in zip(self.weights, self.biases):
            x = torch.baddbmm(b, F.relu(x), w)  # (d, B*M, width)
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
        lay = config.columns
        self.normaliser = Normaliser(lay.width)
        for name, spans in (
            ("obs_columns", lay.observed),
            ("query_columns", lay.query),
            ("out_columns", lay.predicted),
        ):
            self.register_buffer(name, torch.tensor(span_indices(spans), dtype=torch.long), persistent=False)
        H, dy = config.latent_dim, lay.out_dim
        time_dim = 1 + 2 * config.time_frequencies
        self.register_buffer("frequencies", math.pi * torch.arange(1, config.time_frequencies + 1.0), persistent=False)
        self.components = K = config.components()
        if K is not None:  # the observed-only context values are read as K principal components (models.projection)
            projected = [i for a, b in self.observed_only_columns() for i in range(a, b)]
            kept = sorted(set(range(1, 1 + lay.obs_dim)) - set(projected))
            self.register_buffer("projected_values", torch.tensor(projected, dtype=torch.long), persistent=False)
            self.register_buffer("kept_values", torch.tensor([0, *kept], dtype=torch.long), persistent=False)
            self.register_buffer("feature_projection", torch.zeros(len(projected), K))  # fitted: build_model
        self.encoder = mlp([time_dim + self.context_width - 1, *config.encoder_widths])
        self.gate = nn.Linear(H, config.n_experts)
        self.experts = Experts(config.n_experts, H, time_dim + lay.query_dim, [*config.expert_widths, 2 * dy])

    @property
    def n_experts(self) -> int:
        return self.config.n_experts

    def observed_only_columns(self) -> list[tuple[int, int]]:
        """Spans (start, stop) of a context's values (..., 1 + obs_dim), t first, that carry a column the model
        observes but does not predict (such as image features)."""
        observed_only = set(self.config.columns.observed_only)
        spans: list[tuple[int, int]] = []
        for i, column in enumerate(span_indices(self.config.columns.observed), start=1):
            if column not in observed_only:
                continue
            if spans and spans[-1][1] == i:
                spans[-1] = (spans[-1][0], i + 1)
            else:
                spans.append((i, i + 1))
        return spans

    @property
    def context_width(self) -> int:
        """Width of a context as the encoder reads it (`project`): 1 + obs_dim, or with `feature_components` = K, t,
        the observed columns it predicts, then the K components."""
        K = self.components
        return 1 + self.config.columns.obs_dim if K is None else len(self.kept_values) + K

    def observed_only_inputs(self) -> list[tuple[int, int]]:
        """Spans of the encoder's inputs (`encoder_inputs`: t's 1 + 2 time_frequencies features, then the projected
        values) that carry the observed-only columns (`observed_only_columns`), or their principal components."""
        shift = 2 * self.config.time_frequencies
        if self.components is not None:
            return [(shift + self.context_width - self.components, shift + self.context_width)]
        return [(a + shift, b + shift) for a, b in self.observed_only_columns()]

    def project(self, obs: torch.Tensor, projection: torch.Tensor | None = None) -> torch.Tensor:
        """Contexts (..., 1 + obs_dim) as the encoder reads them (..., context_width): as they are, or with the
        observed-only values replaced by their `feature_components` principal components (models.projection), after
        the others. projection: (n, K), default this model's `feature_projection` (models.batched passes each
        stacked model's own)."""
        if self.components is None:
            return obs
        projection = self.feature_projection if projection is None else projection
        components = obs.index_select(-1, self.projected_values) @ projection  # (..., K)
        return torch.cat([obs.index_select(-1, self.kept_values), components], dim=-1)

    def encoder_inputs(self, obs: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
        """The encoder's inputs (..., 2 time_frequencies + context_width) of contexts (..., 1 + obs_dim): `project`ed,
        then the time's Fourier features, then `dropped`."""
        return self.dropped(self.embed_time(self.project(obs)), keep)

    def dropped(self, x: torch.Tensor, keep: torch.Tensor | None) -> torch.Tensor:
        """Encoder inputs `x` (..., 2 time_frequencies + context_width) with their `observed_only_inputs` times `keep`
        (..., their width): the observed-only dropout of training (models.train.dropout_keep); None: `x` as it is."""
        if keep is None:
            return x
        factor = torch.ones_like(x)
        at = 0
        for a, b in self.observed_only_inputs():
            factor[..., a:b] = keep[..., at : at + b - a]
            at += b - a
        return x * factor

    def embed_time(self, x: torch.Tensor) -> torch.Tensor:
        """(..., 1 + k) with t first -> (..., 1 + 2K + k) with the time's Fourier features."""
        if not len(self.frequencies):
            return x
        angle = x[..., :1] * self.frequencies  # (..., K)
        return torch.cat([x[..., :1], angle.sin(), angle.cos(), x[..., 1:]], dim=-1)

    def encode(self, obs: torch.Tensor, obs_mask: torch.Tensor, keep: torch.Tensor | None = None) -> torch.Tensor:
        """Masked mean of the observation encodings: (B, N, 1+obs_dim), (B, N) -> (B, H); keep: as in
        `encoder_inputs`."""
        w = obs_mask.to(obs.dtype).unsqueeze(-1)  # (B, N, 1)
        enc = self.encoder(self.encoder_inputs(obs, keep)) * w  # (B, N, H); padded rows contribute exactly 0
        return enc.sum(1) / w.sum(1).clamp_min(1.0)  # (B, H)

    def decode(self, r: torch.Tensor, query: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """All experts at once: r (B, H), query (B, M, dq) -> mean, std (B, d, M, dy)."""
        B, M, _ = query.shape
        d, dy = self.n_experts, self.config.columns.out_dim
        out = self.experts(r, self.embed_time(query))  # (d, B*M, 2dy)
        out = out.view(d, B, M, 2 * dy).transpose(0, 1)  # (B, d, M, 2dy)
        mean, raw = out.split(dy, dim=-1)  # (B, d, M, dy) each
        return mean, self.config.min_std + F.softplus(raw)

    def forward(
        self,
        obs: torch.Tensor,
        obs_mask: torch.Tensor,
        query: torch.Tensor,
        latent: bool = False,
        keep: torch.Tensor | None = None,
    ):
        """Normalised inputs -> (mean, std (B, d, M, dy), gate (B, d)); with `latent`, the latent r (B, H) too; keep:
        the training contexts' observed-only dropout (`encoder_inputs`)."""
        r = self.encode(obs, obs_mask, keep)  # (B, H)
        gate = torch.softmax(self.gate(r), dim=-1)  # (B, d)
        mean, std = self.decode(r, query)
        return (mean, std, gate, r) if latent else (mean, std, gate)

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
        None when the model has no query columns. `mixture=False` is winner-take-all (the paper's
        inference), `mixture=True` the gate-weighted mixture of expert means (CNEP-MoE).
        """
        lay = self.config.columns
        obs_values = np.asarray(obs_values, dtype=np.float32).reshape(len(obs_t), lay.obs_dim)
        if query_values is None:
            if lay.query_dim:
                raise ConfigError(f"This model's queries carry {lay.query_dim} columns; pass query_values.")
            query_values = np.zeros((len(query_t), 0), dtype=np.float32)
        query_values = np.asarray(query_values, dtype=np.float32).reshape(len(query_t), lay.query_dim)
        p = next(self.parameters())
        on = {"dtype": p.dtype, "device": p.device}  # the model's: a GPU model generates on the GPU
        obs = self.prepare(torch.as_tensor(obs_t, **on), torch.as_tensor(obs_values, **on), self.obs_columns)
        query = self.prepare(torch.as_tensor(query_t, **on), torch.as_tensor(query_values, **on), self.query_columns)
        mean, std, gate = self(obs[None], torch.ones(1, len(obs_t), dtype=torch.bool, device=p.device), query[None])
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
