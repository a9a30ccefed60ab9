"""Random conditioning batches gathered from trajectories packed row after row, without Python loops.

Each sample: a trajectory i, n ~ U{1..min(n_max, T_i)} observation steps and m ~ U{1..min(m_max, T_i)}
target steps, each set drawn without replacement (the two sets are independent). Time of step k of a
trajectory of length T is k / (T - 1), so 0 and 1 are both reachable. A share of the samples
(`TrainConfig.first_steps_fraction`) observe the trajectory's first k ~ U{1..first_steps_max} steps instead: the
context a robot has before it moves, from which a deployed model reads which behaviour to follow. Another share
(`TrainConfig.online_contexts`) observe what the deployed policy conditions on at a step k (its first `anchors` steps
and the latest `window` steps after them, runtime.ConditioningPolicy) and target steps after k, as the policy queries
its next waypoints; k is 0, the policy's first read, in FIRST_READ_SHARE of them, else k ~ U{0..T_i - 2}, and their
context holds up to max(n_max, anchors + window) steps. Training batches may add noise to the observed values
(`TrainConfig.obs_noise`); the targets always stay clean.

Each sample also names its trajectory (`Batch.trajectory`), so that the loss can read the whole demonstration a
context came from (`TrajectoryStack.demonstration`: the steps that decide which expert learns the sample,
models.loss).

The trajectories' rows stay as they were given, (R, width) float32 one trajectory after another (a memory-mapped
file for `pipeline.train`'s data sets: `TrajectoryStack.from_rows`); a batch reads only the rows it draws and
normalises them then, as a padded copy normalised in advance would: a step past a trajectory's end (drawn where it is
shorter than the batch's most steps, and masked) reads as a row of zeros. A trajectory may be held at its last row
for some steps past its end (`held`; which ones and for how long: pipeline.train.hold): those steps read its last row,
and its times run over them as over its own.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch

from cnep.models.schedule import FIRST_READ_SHARE

# The most steps of a demonstration that decide which expert learns a sample of it (`TrajectoryStack.demonstration`),
# evenly spaced over a longer one: enough to tell behaviours apart, a bounded cost per training step.
DEMONSTRATION_STEPS = 64


@dataclasses.dataclass
class Batch:
    obs: torch.Tensor  # (B, n_max, 1 + obs_dim)
    obs_mask: torch.Tensor  # (B, n_max) bool
    query: torch.Tensor  # (B, m_max, 1 + query_dim)
    target: torch.Tensor  # (B, m_max, dy)
    target_mask: torch.Tensor  # (B, m_max) bool
    trajectory: torch.Tensor  # (B,) long: the stack index of each sample's trajectory
    # (B, n_max, observed-only inputs): the training contexts' dropout (models.train.dropout_keep); None: none
    keep: torch.Tensor | None = None

    def to(self, device: torch.device) -> Batch:
        """This batch on `device` (itself, not a copy, where it is there already)."""
        fields = (getattr(self, f.name) for f in dataclasses.fields(self))
        return Batch(*(None if x is None else x.to(device) for x in fields))


class TrajectoryStack:
    """Trajectories packed into one array of rows, read by (trajectory, step) and normalised by the model's normaliser.

    rows: (R, width) float32 (an array or a memory map); starts, lengths: (N,) long, trajectory i's rows are
    rows[starts[i]:starts[i] + lengths[i]]; held: (N,) long or None, steps trajectory i is held at its last row past
    its end (its steps then number lengths[i] + held[i], the held ones reading its last row: the recording run on with
    nothing moving); `longest`: the most steps of one.
    """

    def __init__(self, trajectories: Sequence[np.ndarray], model, held: Sequence[int] | None = None) -> None:
        lengths = [len(t) for t in trajectories]
        rows = np.concatenate([np.asarray(t, dtype=np.float32) for t in trajectories])  # (R, width)
        starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
        self._set(rows, starts, lengths, model, held)

    @classmethod
    def from_rows(
        cls, rows: np.ndarray, starts: Sequence[int], lengths: Sequence[int], model, held: Sequence[int] | None = None
    ) -> TrajectoryStack:
        """The stack of the trajectories at `starts` (rows) of `lengths` in (R, width) float32 `rows`, kept as given,
        each held `held` steps at its last row."""
        stack = cls.__new__(cls)
        stack._set(rows, starts, lengths, model, held)
        return stack

    def _set(
        self, rows: np.ndarray, starts: Sequence[int], lengths: Sequence[int], model, held: Sequence[int] | None
    ) -> None:
        self.rows = rows  # (R, width)
        self.starts = torch.as_tensor(np.asarray(starts, dtype=np.int64))  # (N,)
        self.last = torch.as_tensor(np.asarray(lengths, dtype=np.int64)) - 1  # (N,) each one's last row
        held = np.zeros(len(self.last), dtype=np.int64) if held is None else np.asarray(held, dtype=np.int64)
        if held.shape != self.last.shape or (held < 0).any():
            raise ValueError(f"held must give {len(self.last)} step counts >= 0, got {held.tolist()}")
        self.lengths = self.last + 1 + torch.as_tensor(held)  # (N,) its steps, the held ones included
        self.longest = int(self.lengths.max())
        self.loc = model.normaliser.loc.detach().cpu().clone()  # (width,)
        self.scale = model.normaliser.scale.detach().cpu().clone()  # (width,)
        layout = model.config.columns
        self.observed, self.query, self.predicted = layout.observed, layout.query, layout.predicted  # column spans

    def values(self, traj: torch.Tensor, steps: torch.Tensor, spans: Sequence[tuple[int, int]]) -> torch.Tensor:
        """Normalised values on column `spans` of trajectories `traj` (B,) at `steps` (B, k) -> (B, k, width of
        spans); a step at or past a trajectory's end reads as a row of zeros."""
        B, k = steps.shape
        valid = steps < self.lengths[traj].unsqueeze(1)  # (B, k)
        row = torch.minimum(torch.where(valid, steps, 0), self.last[traj].unsqueeze(1))  # a held step: the last row
        flat = (self.starts[traj].unsqueeze(1) + row).reshape(-1).numpy()  # (B * k,)
        raw = np.concatenate([self.rows[flat, a:b] for a, b in spans] or [np.empty((B * k, 0), np.float32)], axis=1)
        x = torch.from_numpy(np.ascontiguousarray(raw, dtype=np.float32)).reshape(B, k, -1)  # (B, k, w)
        x = x.masked_fill(~valid.unsqueeze(-1), 0.0)
        columns = torch.cat([torch.arange(a, b) for a, b in spans]) if spans else torch.zeros(0, dtype=torch.long)
        return (x - self.loc[columns]) / self.scale[columns]

    def __len__(self) -> int:
        return len(self.lengths)

    def times(self, traj: torch.Tensor, steps: torch.Tensor) -> torch.Tensor:
        """Normalised time of `steps` (B, k) of trajectories `traj` (B,) -> (B, k)."""
        return steps / (self.lengths[traj] - 1).clamp_min(1).unsqueeze(1)

    def spread(self, traj: torch.Tensor, most: int = DEMONSTRATION_STEPS) -> tuple[torch.Tensor, torch.Tensor]:
        """Every step of each trajectory `traj` (B,) of at most `most` steps, else `most` steps evenly spaced from its
        first to its last -> steps (B, P) and mask (B, P) bool, with P = min(most, longest trajectory)."""
        lengths = self.lengths[traj].unsqueeze(1)  # (B, 1)
        P = min(most, self.longest)
        order = torch.arange(P)  # (P,)
        spread = torch.round(order * (lengths - 1) / max(P - 1, 1)).long()  # (B, P): first to last step
        return torch.where(lengths > P, spread, order), order < lengths

    def demonstration(
        self, traj: torch.Tensor, most: int = DEMONSTRATION_STEPS
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Trajectories `traj` (B,) at their `spread` steps as queries and targets -> query (B, P, 1 + query_dim),
        target (B, P, dy), mask (B, P) bool."""
        steps, mask = self.spread(traj, most)
        query = torch.cat([self.times(traj, steps).unsqueeze(-1), self.values(traj, steps, self.query)], -1)
        return query, self.values(traj, steps, self.predicted), mask

    def context(self, traj: torch.Tensor, most: int = DEMONSTRATION_STEPS) -> tuple[torch.Tensor, torch.Tensor]:
        """Trajectories `traj` (B,) at their `spread` steps as observations -> obs (B, P, 1 + obs_dim), mask (B, P)."""
        steps, mask = self.spread(traj, most)
        obs = torch.cat([self.times(traj, steps).unsqueeze(-1), self.values(traj, steps, self.observed)], -1)
        return obs, mask


def _random_steps(lengths: torch.Tensor, k_max: int, T: int, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Up to k_max distinct random steps below each length: indices (B, k) and mask (B, k)."""
    B = len(lengths)
    keys = torch.rand(B, T, generator=g)  # (B, T)
    keys.masked_fill_(torch.arange(T) >= lengths.unsqueeze(1), 2.0)  # invalid steps sort last
    k = min(k_max, T)
    steps = keys.topk(k, dim=1, largest=False).indices  # (B, k) a random subset of valid steps
    limit = torch.minimum(lengths, torch.tensor(k_max))  # (B,)
    count = 1 + (torch.rand(B, generator=g) * limit).long()  # (B,) ~ U{1..limit}
    mask = torch.arange(k) < count.unsqueeze(1)  # (B, k)
    return steps, mask


def _first_steps(
    steps: torch.Tensor, mask: torch.Tensor, lengths: torch.Tensor, fraction: float, k_max: int, g: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """`steps`, `mask` (B, n) with each sample, at probability `fraction`, replaced by the trajectory's first
    k ~ U{1..k_max} steps (at most n and its length)."""
    B, n = steps.shape
    first = torch.rand(B, generator=g) < fraction  # (B,)
    k = 1 + (torch.rand(B, generator=g) * k_max).long()  # (B,) ~ U{1..k_max}
    order = torch.arange(n)  # the first n steps, in order
    first_mask = order < torch.minimum(k, lengths).unsqueeze(1)  # (B, n)
    return torch.where(first[:, None], order, steps), torch.where(first[:, None], first_mask, mask)


def _online_steps(
    obs: tuple[torch.Tensor, torch.Tensor],
    tgt: tuple[torch.Tensor, torch.Tensor],
    lengths: torch.Tensor,
    online: tuple[float, int, int],
    g: torch.Generator,
) -> tuple[tuple[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]:
    """(steps, mask) of the observations (B, n) and targets (B, m) with each sample, at probability `online[0]`,
    observing what the deployed policy conditions on at a step k (0, its first read, at probability FIRST_READ_SHARE,
    else k ~ U{0..T_i - 2}): its first `anchors` steps and the latest `window` after them (online = (fraction,
    window, anchors), anchors + window <= n); and targeting m' ~ U{1..min(m, T_i - 1 - k)} steps drawn from those
    after k (step 0 for a one-step trajectory)."""
    (obs_steps, obs_mask), (tgt_steps, tgt_mask) = obs, tgt
    fraction, window, anchors = online
    (B, n), m = obs_steps.shape, tgt_steps.shape[1]
    chosen = (torch.rand(B, generator=g) < fraction)[:, None]  # (B, 1)
    k = (torch.rand(B, generator=g) * (lengths - 1).clamp_min(1)).long()  # (B,) the step reached
    k = torch.where(torch.rand(B, generator=g) < FIRST_READ_SHARE, 0, k)[:, None]  # (B, 1)
    order = torch.arange(n)  # columns: the anchors, then the window's oldest to newest
    first = torch.minimum(torch.tensor(anchors), k + 1)  # (B, 1) anchors seen by step k
    steps = torch.where(order < anchors, order, k - (anchors + window - 1) + order)  # (B, n)
    mask = torch.where(order < anchors, order < first, (steps >= first) & (order < anchors + window))
    after = (lengths[:, None] - 1 - k).clamp_min(1)  # (B, 1) steps after k (1: the step itself, one-step trajectory)
    future = torch.minimum(k + 1, lengths[:, None] - 1) + (torch.rand(B, m, generator=g) * after).long()  # (B, m)
    count = 1 + (torch.rand(B, 1, generator=g) * torch.clamp(after, max=m)).long()  # (B, 1) ~ U{1..min(m, after)}
    return (
        (torch.where(chosen, steps.clamp_min(0), obs_steps), torch.where(chosen, mask, obs_mask)),
        (torch.where(chosen, future, tgt_steps), torch.where(chosen, torch.arange(m) < count, tgt_mask)),
    )


def sample_batch(
    stack: TrajectoryStack,
    batch_size: int,
    n_max: int,
    m_max: int,
    g: torch.Generator,
    obs_noise: float = 0.0,
    first_steps: tuple[float, int] = (0.0, 1),
    online: tuple[float, int, int] = (0.0, 1, 0),
) -> Batch:
    """A batch; `obs_noise` > 0 adds Gaussian noise of that std to the observed values (not the times);
    `first_steps` (fraction, k_max): the share of samples that observe their trajectory's first k ~ U{1..k_max} steps;
    `online` (fraction, window, anchors): the share of samples that observe what the deployed policy does at a random
    step and target the steps after it (`_online_steps`; the context then holds max(n_max, anchors + window) steps).
    A fraction of 0 draws nothing for it, so the batches are those drawn without it."""
    traj = torch.randint(len(stack), (batch_size,), generator=g)  # (B,)
    lengths, T = stack.lengths[traj], stack.longest
    obs_steps, obs_mask = _random_steps(lengths, n_max, T, g)  # (B, n)
    tgt_steps, tgt_mask = _random_steps(lengths, m_max, T, g)  # (B, m)
    if first_steps[0] > 0:
        obs_steps, obs_mask = _first_steps(obs_steps, obs_mask, lengths, *first_steps, g)
    if online[0] > 0:
        width = online[1] + online[2]
        if width > obs_steps.shape[1]:  # room for the deployed set: masked columns after the random contexts
            pad = width - obs_steps.shape[1]
            obs_steps = torch.cat([obs_steps, torch.zeros(batch_size, pad, dtype=obs_steps.dtype)], 1)
            obs_mask = torch.cat([obs_mask, torch.zeros(batch_size, pad, dtype=torch.bool)], 1)
        (obs_steps, obs_mask), (tgt_steps, tgt_mask) = _online_steps(
            (obs_steps, obs_mask), (tgt_steps, tgt_mask), lengths, online, g
        )
    values = stack.values(traj, obs_steps, stack.observed)  # (B, n, obs_dim)
    if obs_noise:
        values = values + obs_noise * torch.randn(values.shape, generator=g)
    obs = torch.cat([stack.times(traj, obs_steps).unsqueeze(-1), values], -1)
    query = torch.cat([stack.times(traj, tgt_steps).unsqueeze(-1), stack.values(traj, tgt_steps, stack.query)], -1)
    return Batch(obs, obs_mask, query, stack.values(traj, tgt_steps, stack.predicted), tgt_mask, traj)
