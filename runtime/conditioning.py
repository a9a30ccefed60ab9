"""Online conditioning of a CNEP, in numpy, over any network that encodes observations and decodes a latent.

The paper's "online conditioning and on-the-fly adaptation": at each step the current observation (a
model row: features, pose, gripper at time t) enters the conditioning set, the gate is re-evaluated, and
the active expert may switch. The authors' code has no such mode; this is ours.

Conditioning policy (`ConditioningPolicy`): the set at step k is
    the first `anchors` observations of the episode (kept for the whole episode: the start point by
    default, which fixes where the movement began) + the latest `window` observations after them.
The encoder's latent is a masked mean of per-observation encodings, so the conditioner keeps a running
sum of the encodings in the set (float64): one encoder row per step is added, the one leaving the window
is subtracted. A step costs O(1) (one encoder row, the gate, the queries of every expert), whatever the
episode's length.

Which expert is active: at step 0, the gate's argmax (`first_expert="argmax"`, winner-take-all) or an expert
drawn from the gate's probabilities with the episode's seeded generator (`first_expert="sample"`: where the
demonstrations split between behaviours, episodes split alike). After it, the gate's leader takes over
when it leads the active expert by at least `switch_margin`, or when the active expert's probability has
fallen by at least `switch_margin` over the last `switch_window` steps (0 margin: the argmax at every step).
A gate that wavers near a tie keeps its expert; a change in the scene, which moves the gate steadily from
one expert to another, switches where the two cross, as the argmax would.

The network is anything with `encode` and `decode` (`Network`): the torch CNEP (models.online) and the
exported ONNX graphs (runtime.exported) both are, so the logic here exists once for both. Rows are
normalised here, with the statistics the model was trained with (`Columns`). Query columns (if the layout
has any) of predicted future steps are held at the current row's values, since future observations are
unknown.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from typing import Protocol

import numpy as np

from cnep.runtime.errors import PolicyError
from cnep.runtime.spans import Spans, span_indices

FIRST_EXPERTS = ("argmax", "sample")  # how the first active expert of an episode is chosen


@dataclass(frozen=True)
class ConditioningPolicy:
    """Which observations condition the model (`anchors` first ones, fixed, + the latest `window`) and which
    expert is active (the first by `first_expert`, then kept unless the evidence moves: `switch_margin`,
    `switch_window`)."""

    window: int = field(default=10, metadata={"help": "latest observations in the conditioning set"})
    anchors: int = field(
        default=1,
        metadata={"help": "first observations kept in the conditioning set for the whole episode (1: the start)"},
    )
    first_expert: str = field(
        default="argmax",
        metadata={
            "help": "the first active expert of an episode: argmax (the gate's winner) or sample (drawn from the "
            "gate's probabilities with the episode's seed: episodes split as the demonstrations do)",
            "choices": FIRST_EXPERTS,
        },
    )
    switch_margin: float = field(
        default=0.3,
        metadata={
            "help": "the gate's leader takes over from the active expert when it leads it by at least this much "
            "probability, or when the active expert's probability fell by this much over the last switch-window "
            "steps (0: the gate's argmax at every step)"
        },
    )
    switch_window: int = field(
        default=3,
        metadata={
            "help": "steps over which a fall of the active expert's probability by the switch margin hands over to "
            "the leader without the margin (0: the margin alone)"
        },
    )

    def __post_init__(self) -> None:
        if self.window < 1:
            raise PolicyError(f"ConditioningPolicy.window must be >= 1 (the current observation), got {self.window}.")
        if self.anchors < 0:
            raise PolicyError(f"ConditioningPolicy.anchors must be >= 0, got {self.anchors}.")
        if self.first_expert not in FIRST_EXPERTS:
            raise PolicyError(
                f"ConditioningPolicy.first_expert must be one of {', '.join(FIRST_EXPERTS)}, got {self.first_expert!r}."
            )
        if not 0.0 <= self.switch_margin < 1.0:
            raise PolicyError(f"ConditioningPolicy.switch_margin must be in [0, 1), got {self.switch_margin}.")
        if self.switch_window < 0:
            raise PolicyError(f"ConditioningPolicy.switch_window must be >= 0, got {self.switch_window}.")

    def to_dict(self) -> dict:
        """JSON-able: the manifest's `spec.conditioning` and the checkpoint's `conditioning`."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict | None) -> ConditioningPolicy:
        """The policy of `to_dict` (a setting it lacks keeps its default; None: every default, as a checkpoint or
        manifest written before it was stored reads); PolicyError naming an unknown setting or a wrong value."""
        data = {} if data is None else data
        if not isinstance(data, dict):
            raise PolicyError(f"the conditioning settings are a JSON object, got {type(data).__name__}")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise PolicyError(f"unknown conditioning setting(s) {unknown}; known: {names}")
        kinds = {f.name: type(f.default) for f in fields(cls)}
        for name, value in data.items():
            number = kinds[name] is float and isinstance(value, int)
            if isinstance(value, bool) or not (isinstance(value, kinds[name]) or number):
                raise PolicyError(f"conditioning setting {name} must be a {kinds[name].__name__}, got {value!r}")
        return cls(**data)


@dataclass(frozen=True)
class ExpertSwitch:
    """The active expert changed at `step`: `from_expert` -> `to_expert`, with the new gate (d,)."""

    step: int
    t: float  # normalised time in [0, 1]
    timestamp_ns: int | None
    from_expert: int
    to_expert: int
    gate: np.ndarray


def hand_over(policy: ConditioningPolicy, recent: Sequence[np.ndarray], active: int) -> int:
    """The active expert after the gate `recent[-1]` (d,), `active` before it: the gate's leader where it leads
    `active` by `policy.switch_margin`, or where `active`'s probability fell by that much since the gate
    `policy.switch_window` steps earlier, `recent[-1 - switch_window]` (`recent`: the latest gates, oldest first;
    fewer at an episode's start, where only the margin counts); else `active`."""
    gate = recent[-1]
    leader = int(gate.argmax())
    if leader == active:
        return active
    margin = policy.switch_margin
    fell = len(recent) > policy.switch_window > 0 and recent[-1 - policy.switch_window][active] - gate[active] >= margin
    return leader if gate[leader] - gate[active] >= margin or fell else active


def checked_seed(seed: object) -> int:
    """`seed` as an episode's seed: an integer >= 0 (numpy's too); PolicyError for anything else."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise PolicyError(f"an episode's seed is an integer >= 0 (or None: the policy's own generator), got {seed!r}")
    return int(seed)


class Network(Protocol):
    """A trained CNEP's networks on normalised float32 arrays (H latent, d experts, dy predicted columns)."""

    def encode(self, obs: np.ndarray) -> np.ndarray:
        """[t, observed columns] (N, 1 + obs_dim) -> encodings (N, H)."""

    def decode(self, r: np.ndarray, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Latent (1, H), queries [t, query columns] (M, 1 + query_dim) -> gate (d,), mean and std (d, M, dy)."""


@dataclass(frozen=True)
class Columns:
    """Which columns of a `(width,)` model row the network observes, queries with and predicts (spans), and the
    normaliser's per-column `loc` and `scale` (width,) that map the row to the network's units."""

    observed: Spans
    query: Spans
    predicted: Spans
    loc: np.ndarray
    scale: np.ndarray

    def __post_init__(self) -> None:
        loc, scale = np.asarray(self.loc, dtype=np.float32), np.asarray(self.scale, dtype=np.float32)
        width = loc.shape[0] if loc.ndim == 1 else -1
        if loc.shape != scale.shape or width < 1 or not (np.isfinite(loc).all() and (scale > 0).all()):
            raise PolicyError(
                f"the normaliser needs finite loc and positive scale of one width, got shapes {loc.shape} and "
                f"{scale.shape}"
            )
        for name in ("observed", "query", "predicted"):
            spans = tuple((int(a), int(b)) for a, b in getattr(self, name))
            if any(not 0 <= a < b <= width for a, b in spans):
                raise PolicyError(f"the {name} columns {spans} do not fit a row of {width} columns")
            object.__setattr__(self, name, spans)
        object.__setattr__(self, "loc", loc)
        object.__setattr__(self, "scale", scale)

    @property
    def width(self) -> int:
        return int(self.loc.shape[0])


class Conditioner:
    """The conditioning state of one episode (`reset()` starts a new one) over `network`."""

    def __init__(self, network: Network, columns: Columns, policy: ConditioningPolicy = ConditioningPolicy()) -> None:
        self.network, self.columns, self.policy = network, columns, policy
        self._obs_cols = np.array(span_indices(columns.observed), dtype=np.intp)
        self._query_cols = np.array(span_indices(columns.query), dtype=np.intp)
        out_cols = np.array(span_indices(columns.predicted), dtype=np.intp)
        self._obs_loc, self._obs_scale = columns.loc[self._obs_cols], columns.scale[self._obs_cols]
        self._q_loc, self._q_scale = columns.loc[self._query_cols], columns.scale[self._query_cols]
        self._out_loc, self._out_scale = columns.loc[out_cols], columns.scale[out_cols]
        # Buffers reused at every step: the encoder's input row and the decoder's queries.
        self._obs = np.empty((1, 1 + len(self._obs_cols)), dtype=np.float32)  # (1, 1 + obs_dim)
        self._query_values = np.empty(len(self._query_cols), dtype=np.float32)  # (query_dim,) normalised
        self._queries = np.empty((0, 1 + len(self._query_cols)), dtype=np.float32)  # (M, 1 + query_dim)
        self._rng = np.random.default_rng(0)  # the draws of `first_expert="sample"`; reset(seed) replaces it
        self.reset()

    @property
    def width(self) -> int:
        """Columns of a model row."""
        return self.columns.width

    def reset(self, seed: int | None = None) -> None:
        """Forget the conditioning set: the next `step` is step 0 of a new episode.

        seed: the generator of the episode's draws (`first_expert="sample"`): the same seed, the same draw; None
        continues the conditioner's generator (seeded 0 when it is made, so a run of episodes is reproducible).
        PolicyError for a seed that is not an integer >= 0.
        """
        if seed is not None:
            self._rng = np.random.default_rng(checked_seed(seed))
        self.k = 0  # index of the next step
        self._sum: np.ndarray | None = None  # (H,) float64 running sum of the encodings in the set
        self._n = 0  # observations in the set
        self._ring: np.ndarray | None = None  # (window, H) float64: encodings of the sliding part
        self._in_ring = 0  # encodings held in the ring; the oldest is at (self._next - self._in_ring) % window
        self._next = 0  # where the next encoding goes in the ring
        self._r: np.ndarray | None = None  # (1, H) float32 latent of the current set, the mean of the encodings
        self.gate: np.ndarray | None = None
        self.expert: int | None = None
        self._gates: deque[np.ndarray] = deque(maxlen=self.policy.switch_window + 1)  # the latest gates (d,)

    @property
    def n_conditioning(self) -> int:
        """Number of observations in the current conditioning set."""
        return self._n

    def step(
        self, row: np.ndarray, t: float, query_t: np.ndarray, timestamp_ns: int | None = None
    ) -> tuple[np.ndarray, int, ExpertSwitch | None, np.ndarray, np.ndarray]:
        """Condition on `row` (width,) at phase `t`, re-evaluate the gate, predict at phases `query_t` (M,).

        Returns gate (d,), the active expert, the switch (None unless the expert changed at this step), and the
        active expert's mean and std (M, dy) in the data's units.
        """
        obs = self._obs
        obs[0, 0] = t
        np.take(row, self._obs_cols, out=obs[0, 1:])
        np.subtract(obs[0, 1:], self._obs_loc, out=obs[0, 1:])
        np.divide(obs[0, 1:], self._obs_scale, out=obs[0, 1:])
        np.take(row, self._query_cols, out=self._query_values)
        np.subtract(self._query_values, self._q_loc, out=self._query_values)
        np.divide(self._query_values, self._q_scale, out=self._query_values)
        encoding = self.network.encode(obs)[0]  # (H,)
        if not np.isfinite(encoding).all():  # checked before it joins the set, which it would spoil for the episode
            raise PolicyError(
                f"step {self.k}: the encoder gave values that are not finite for this observation; it was left out "
                f"of the conditioning set"
            )
        self._add(encoding)
        np.divide(self._sum, self._n, out=self._r[0], casting="same_kind")  # (1, H) the mean over the set
        gate, mean, std = self.network.decode(self._r, self._fill_queries(query_t))  # (d,), (d, M, dy) x 2
        if not (np.isfinite(gate).all() and np.isfinite(mean).all() and np.isfinite(std).all()):
            raise PolicyError(
                f"step {self.k}: the model's gate or predictions are not finite (its graphs or weights are damaged); "
                f"no action was given: reset() and export the checkpoint again"
            )
        self._gates.append(gate)
        expert = self._active(gate)
        switch = None
        if self.expert is not None and expert != self.expert:
            switch = ExpertSwitch(self.k, float(t), timestamp_ns, self.expert, expert, gate)
        self.gate, self.expert = gate, expert
        self.k += 1
        return gate, expert, switch, self._denormalise_mean(mean[expert]), std[expert] * self._out_scale

    def _active(self, gate: np.ndarray) -> int:
        """The active expert after this step's gate (d,): the first by the policy, then `hand_over`'s."""
        if self.expert is not None:
            return hand_over(self.policy, self._gates, self.expert)
        if self.policy.first_expert == "argmax":
            return int(gate.argmax())
        cumulative = np.cumsum(gate, dtype=np.float64)
        drawn = int(np.searchsorted(cumulative, self._rng.random() * cumulative[-1], side="right"))
        return min(drawn, len(gate) - 1)

    def predict(self, query_t: np.ndarray, all_experts: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Predict at phases `query_t` (m,) from the current set, in the data's units.

        Returns mean, std (m, dy) of the active expert (winner-take-all, the paper's inference); with
        `all_experts=True`, (d, m, dy) for every expert.
        """
        if self._n == 0:
            raise PolicyError("predict needs at least one observation: call step() first.")
        _, mean, std = self.network.decode(self._r, self._fill_queries(query_t))  # (d, m, dy) each
        if all_experts:
            return self._denormalise_mean(mean), std * self._out_scale
        return self._denormalise_mean(mean[self.expert]), std[self.expert] * self._out_scale

    def _denormalise_mean(self, mean: np.ndarray) -> np.ndarray:
        return mean * self._out_scale + self._out_loc

    def _fill_queries(self, query_t: np.ndarray) -> np.ndarray:
        """The (M, 1 + query_dim) queries [t, current query columns] in the reused buffer (grown when M grows)."""
        query_t = np.asarray(query_t)
        m = len(query_t)
        if len(self._queries) != m:
            self._queries = np.empty((m, self._queries.shape[1]), dtype=np.float32)
        self._queries[:, 0] = query_t
        self._queries[:, 1:] = self._query_values
        return self._queries

    def _add(self, enc: np.ndarray) -> None:
        """Put the encoding (H,) of step k into the set by the policy; evict what leaves the window."""
        if self._sum is None:  # the first step of an episode: H is known now
            self._sum = np.zeros(enc.shape, dtype=np.float64)
            self._ring = np.empty((self.policy.window, *enc.shape), dtype=np.float64)
            self._r = np.empty((1, *enc.shape), dtype=np.float32)
        self._sum += enc
        self._n += 1
        if self.k < self.policy.anchors:
            return  # an anchor stays for the whole episode
        window = self.policy.window
        if self._in_ring == window:  # the oldest of the window leaves the set
            self._sum -= self._ring[self._next]
            self._n -= 1
        else:
            self._in_ring += 1
        self._ring[self._next] = enc
        self._next = (self._next + 1) % window
