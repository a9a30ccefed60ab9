"""Configuration of the CNEP model and of its training, validated on construction.

A trajectory is a `(T, C)` float array: one row per time step, `C` columns. `ColumnRoles` says which
columns the encoder observes (besides the time), which extra columns a query carries (besides the
time) and which columns the experts predict (`CNEPConfig.columns`). Columns are given as half-open
`(start, stop)` spans so the 1288 columns of the pipeline's trajectories stay short in `config.json`.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, make_dataclass, replace

from cnep.models.assignments import ASSIGNMENTS, Assignment, assignment_named
from cnep.models.errors import ConfigError
from cnep.models.threads import SMALL_MODEL_THREADS
from cnep.runtime.conditioning import ConditioningPolicy as ConditioningPolicy  # in the runtime: it needs no torch
from cnep.runtime.spans import Spans, span_indices

# The seeds a setting takes: every generator a seed reaches takes these (numpy's legacy ones take 32 bits; torch's and
# Gymnasium's more), so a seed is refused where it is given, not where it first reaches a generator.
SEED_MAX = 2**32 - 1


def in_message(value: object) -> str:
    """`value` as an error message shows it: its repr, at most 60 characters (an integer too long to print is named by
    its size, as Python refuses to print one of more than 4300 digits)."""
    if isinstance(value, int) and not -(10**30) < value < 10**30:
        return f"an integer of {value.bit_length()} bits"
    text = repr(value)
    return text if len(text) <= 60 else f"{text[:57]}..."


def check_seed(option: str, seed: object, error: type[Exception] = ConfigError) -> None:
    """`error` naming `option` unless `seed` is a whole number from 0 to SEED_MAX."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= SEED_MAX:
        raise error(f"{option} must be a whole number from 0 to {SEED_MAX}, got {in_message(seed)}")


def _spans(value, name: str, width: int) -> Spans:
    spans = tuple((int(a), int(b)) for a, b in value)
    for a, b in spans:
        if not 0 <= a < b <= width:
            raise ConfigError(f"Column span {name}=({a}, {b}) must satisfy 0 <= start < stop <= width={width}.")
    return spans


@dataclass(frozen=True)
class ColumnRoles:
    """Which columns of a `(T, width)` trajectory the model observes, queries with and predicts."""

    width: int = 1
    observed: Spans = ((0, 1),)
    query: Spans = ()
    predicted: Spans = ((0, 1),)

    def __post_init__(self) -> None:
        if self.width < 1:
            raise ConfigError(f"The column roles' width must be >= 1, got {self.width}.")
        for name in ("observed", "query", "predicted"):
            object.__setattr__(self, name, _spans(getattr(self, name), name, self.width))
        if not self.observed or not self.predicted:
            raise ConfigError("A model needs at least one observed and one predicted column.")

    @property
    def obs_dim(self) -> int:
        return len(span_indices(self.observed))

    @property
    def query_dim(self) -> int:
        return len(span_indices(self.query))

    @property
    def out_dim(self) -> int:
        return len(span_indices(self.predicted))

    @property
    def observed_only(self) -> tuple[int, ...]:
        """The columns observed but never predicted (such as a camera's image features), in the order observed."""
        predicted = set(span_indices(self.predicted))
        return tuple(c for c in span_indices(self.observed) if c not in predicted)


def setting(
    default: object,
    help: str,
    *,
    option: str | None = None,
    choices: tuple[str, ...] | None = None,
    shown: str | None = None,
) -> object:
    """A dataclass field with its default and the one line that `cnep` shows for it (`--help`, metadata "help").

    The command line (pipeline.cli.fields) offers it as `--NAME` (`option`: another name) within `choices`, its
    default written as `shown` where the value does not say it (None: the policy's own).
    """
    metadata = {"help": help, "option": option, "choices": choices, "shown": shown}
    return field(default=default, metadata={k: v for k, v in metadata.items() if v is not None})


def optional_settings(cls: type, name: str, shown: str) -> type:
    """A frozen dataclass `name` with a field for every setting of the config class `cls` (those with a help text),
    defaulting to None: not given, `cls`'s value stays. Each field keeps the setting's help and choices, its default
    shown as `shown`; `given()` is the settings that are set (name -> value) and `applied(config)` the `cls` instance
    `config` with them replaced. So the options that replace a setting come from its one definition."""
    made = [
        (f.name, f"{f.type} | None", setting(None, f.metadata["help"], choices=f.metadata.get("choices"), shown=shown))
        for f in fields(cls)
        if "help" in f.metadata
    ]

    def given(self) -> dict[str, object]:
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}

    def applied(self, config):
        return replace(config, **given(self))

    def check(self) -> None:
        cls(**given(self))  # the class's own checks, on the given values

    namespace = {"given": given, "applied": applied, "__post_init__": check, "__doc__": optional_settings.__doc__}
    made_cls = make_dataclass(name, made, frozen=True, namespace=namespace)
    made_cls.__module__ = __name__  # where it is defined: pickled and shown by its place here
    return made_cls


# The conditioning settings given where a trained policy runs (`cnep export`, `cnep run`, `cnep sim eval`): each
# replaces the one the policy was trained with (its checkpoint's config.json, its manifest).
ConditioningOverrides = optional_settings(ConditioningPolicy, "ConditioningOverrides", "the policy's own")


# How `cnep train --help` shows the default of a setting the training schedule fills (models.schedule).
SCHEDULE_SHOWN = "the training schedule's, a rule of the training demonstrations (docs/reference/training-recipe.md)"


def authors_coefficients(n_experts: int) -> tuple[float, float, float]:
    """(a_rec, a_batch, a_ind) as the authors rescaled their d=2 sweep: a1*d/2, a2/log2(d), a3/log2(d)."""
    if n_experts == 1:
        return 16.81 / 2, 0.0, 0.0  # CNMP: the entropy terms are meaningless with one expert
    return 16.81 * n_experts / 2, 10.672 / math.log2(n_experts), 7.553 / math.log2(n_experts)


@dataclass(frozen=True)
class CNEPConfig:
    """The network and its loss. `n_experts=1` is a CNMP.

    The loss is `a_rec * L_rec - a_batch * L_batch + a_ind * L_ind` (the paper prints `+ a_batch`; the
    authors' code subtracts it, which matches the stated intent of maximising batch entropy).
    Coefficients left as None take the authors' values rescaled with the number of experts.
    `assignment` names how L_rec assigns targets to the experts (`assigned`: its definition in models.assignments);
    "paper" reproduces the paper's tables, "bounded" (the default) commits where behaviours share a context.
    """

    columns: ColumnRoles = field(default_factory=ColumnRoles)  # which columns it observes, queries with, predicts
    n_experts: int = setting(2, "number of experts; 1 is a CNMP", option="experts")
    encoder_widths: tuple[int, ...] = setting((128, 128), "encoder layer widths (the last is the latent size)")
    expert_widths: tuple[int, ...] = setting((128, 128), "expert layer widths")
    min_std: float = 1e-3  # floor of the predicted std, in normalised units
    time_frequencies: int = 8  # K: t is fed as [t, sin(pi k t), cos(pi k t) for k = 1..K]
    a_rec: float | None = None
    a_batch: float | None = None
    a_ind: float | None = None
    assignment: str = setting(
        "bounded",
        "how the loss assigns a context's targets to the experts: "
        + ", ".join(f"{a.name} = {a.summary}" for a in ASSIGNMENTS.values())
        + " (docs/concepts.md)",
        choices=tuple(ASSIGNMENTS),
    )
    # A few dozen training scenes spread over at most as many directions of the image features' 1280; the encoder
    # reading only those directions cannot tell its training scenes apart by the rest (docs/concepts.md). None: the
    # schedule's where a model is trained (models.schedule.with_components), every column in a model built with it;
    # 0: every column, given.
    feature_components: int | None = setting(
        None,
        "the encoder reads the columns it observes but does not predict (such as image features) as their top K "
        "principal components over the training rows, each scaled to unit variance (0: every column as it is)",
        shown=SCHEDULE_SHOWN,
    )

    def __post_init__(self) -> None:
        assignment_named(self.assignment)
        if isinstance(self.columns, dict):
            object.__setattr__(self, "columns", ColumnRoles(**self.columns))
        object.__setattr__(self, "encoder_widths", tuple(int(w) for w in self.encoder_widths))
        object.__setattr__(self, "expert_widths", tuple(int(w) for w in self.expert_widths))
        if self.n_experts < 1:
            raise ConfigError(f"n_experts must be >= 1, got {self.n_experts}.")
        if not self.encoder_widths or min(self.encoder_widths + self.expert_widths or (1,)) < 1:
            raise ConfigError(
                f"Widths must be positive and the encoder needs at least one layer, got encoder "
                f"{self.encoder_widths} and experts {self.expert_widths}."
            )
        if self.time_frequencies < 0:
            raise ConfigError(f"time_frequencies must be >= 0, got {self.time_frequencies}.")
        if self.feature_components is not None and (
            isinstance(self.feature_components, bool)
            or not isinstance(self.feature_components, int)
            or self.feature_components < 0
        ):
            raise ConfigError(
                f"feature_components must be a whole number >= 0 (0 or none: every column), got "
                f"{in_message(self.feature_components)}."
            )
        if not self.min_std > 0:
            raise ConfigError(f"min_std must be > 0 (it keeps the likelihood finite), got {self.min_std}.")
        defaults = authors_coefficients(self.n_experts)
        for name, default in zip(("a_rec", "a_batch", "a_ind"), defaults):
            value = default if getattr(self, name) is None else float(getattr(self, name))
            if value < 0:
                raise ConfigError(f"{name} must be >= 0 (signs are fixed by the loss), got {value}.")
            object.__setattr__(self, name, value)

    @property
    def latent_dim(self) -> int:
        return self.encoder_widths[-1]

    @property
    def projected_columns(self) -> tuple[int, ...]:
        """The columns the encoder reads as principal components (`components`): the observed-only ones where
        `feature_components` is set, else none. Their scatter matrix is what the training rows' moments must carry."""
        return self.columns.observed_only if self.components() is not None else ()

    def components(self) -> int | None:
        """`feature_components` checked against the columns: None (unset, or 0: every column as it is), or K with
        1 <= K <= the columns observed but not predicted (`ColumnRoles.observed_only`); a ConfigError otherwise."""
        K, n = self.feature_components, len(self.columns.observed_only)
        if not K:
            return None
        if n == 0:
            raise ConfigError(
                f"feature_components={K} projects the columns the model observes but does not predict (such as image "
                f"features), and this model predicts every column it observes; leave it unset"
            )
        if n < K:
            raise ConfigError(
                f"feature_components must be at most the {n} columns the model observes but does not predict, got {K}"
            )
        return K

    @property
    def assigned(self) -> Assignment:
        """The definition of `assignment` (models.assignments): its loss term, gate scale and balancing."""
        return ASSIGNMENTS[self.assignment]

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> CNEPConfig:
        """The config of `to_dict`. A config without `assignment` trained with the paper's term; one whose `columns`
        are named `layout` (a checkpoint's config.json may use either name) is read the same."""
        data = dict(data)
        if "layout" in data and "columns" not in data:
            data["columns"] = data.pop("layout")
        return cls(**{"assignment": "paper", **_known(cls, data)})


@dataclass(frozen=True)
class TrainConfig:
    """How `fit` trains. Steps and widths follow the spec's CPU recipe (see docs/concepts.md); `steps`,
    `warmup_steps` and `val_every` left None are the training schedule's (models.schedule.scheduled), which a
    trainer fills from its data before it starts."""

    # None: the schedule's, a rule of the training data (models.schedule), as are warmup_steps and val_every.
    steps: int | None = setting(None, "training steps", shown=SCHEDULE_SHOWN)
    batch_size: int = setting(32, "samples per step and process")
    n_max: int = setting(10, "most observations per sample (n ~ U{1..n_max})")
    m_max: int = setting(10, "most targets per sample (m ~ U{1..m_max})")
    obs_noise: float = setting(0.0, "std of the noise added to training contexts' observed values (normalised units)")
    # Columns a model observes but never predicts (a camera's 1280 features) reach only the latent, where a few
    # hundred training scenes can each be told apart by their clutter and lighting; decaying those weights keeps what
    # the scenes share (docs/results.md).
    observed_only_decay: float = setting(
        3.0,
        "weight decay of the encoder's weights on the columns it observes but does not predict (such as image "
        "features), per unit of learning rate; 0 turns it off",
    )
    # The same columns, zeroed at random in training contexts: a scene is then read from many of its numbers at once,
    # never from the few that alone told its training scenes apart (docs/concepts.md).
    observed_only_dropout: float = setting(
        0.5,
        "share of the values on the columns the encoder observes but does not predict (such as image features) "
        "zeroed in each training context, the rest scaled by 1 / (1 - share); 0 turns it off",
    )
    # The first steps are the context a robot has before it moves, from which a deployed model reads its behaviour;
    # 0 keeps the paper's random contexts only (where trajectories share their first steps, those tell nothing).
    first_steps_fraction: float = setting(
        0.0, "share of training and validation contexts that are a trajectory's first k ~ U{1..first_steps_max} steps"
    )
    first_steps_max: int = setting(4, "most steps in such a first-steps context")
    # A deployed policy conditions on its first steps and its latest ones, never on steps ahead of it, and queries the
    # steps ahead (runtime.ConditioningPolicy). The paper's random contexts hold steps from anywhere, so they teach a
    # model to read where a motion goes from the late steps it was shown; a context shaped like the policy's teaches
    # it to read that from what the policy has seen by then (models.sampler).
    online_contexts: float | None = setting(
        None,
        "share of training and validation contexts that are what the deployed policy conditions on at a random step "
        "(its anchors and latest window of observations), their targets the steps after it",
        shown=SCHEDULE_SHOWN,
    )
    # Plain NLL lets the well-predicted values outweigh a hard one by the ratio of their variances, and the hard one's
    # mean stops being learned (its std grows instead): where a model must read a value from its context, such as
    # the place a motion heads for, beta > 0 keeps that mean learning (models.loss.expert_nll).
    nll_beta: float = setting(
        0.0,
        "each value's NLL in the training loss weighted by its predicted variance to this power (beta-NLL); 0 is the "
        "paper's plain NLL, 0.5 the usual beta-NLL",
    )
    lr: float = setting(1e-3, "peak learning rate of Adam")
    warmup_steps: int | None = setting(None, "steps of linear learning-rate warm-up", shown=SCHEDULE_SHOWN)
    gate_freeze_fraction: float = setting(0.3, "share of the steps with the gate held uniform")
    gate_lr_scale: float | None = setting(None, "the gate's learning rate as a fraction of the learning rate")
    grad_clip: float = 10.0
    val_every: int | None = setting(None, "steps between validations", shown=SCHEDULE_SHOWN)
    patience: int | None = setting(10, "validations without improvement before stopping early")
    seed: int = setting(0, "seed of the initial weights, the validation split and the batches")
    threads: int | None = setting(SMALL_MODEL_THREADS, "torch threads per process while training")

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "n_max", "m_max", "val_every"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ConfigError(f"TrainConfig.{name} must be >= 1, got {getattr(self, name)}.")
        if not 0 <= self.gate_freeze_fraction < 1:
            raise ConfigError(f"gate_freeze_fraction must be in [0, 1), got {self.gate_freeze_fraction}.")
        if self.gate_lr_scale is not None and not self.gate_lr_scale > 0:
            raise ConfigError(
                f"gate_lr_scale must be > 0 (use gate_freeze_fraction to hold the gate), got {self.gate_lr_scale}."
            )
        if not 0 <= self.nll_beta <= 1:
            raise ConfigError(
                f"nll_beta must be in [0, 1] (0: plain NLL; 0.5: the usual beta-NLL), got {self.nll_beta}."
            )
        if self.online_contexts is not None and not 0 <= self.online_contexts <= 1:
            raise ConfigError(f"online_contexts must be in [0, 1], got {self.online_contexts}.")
        if not 0 <= self.first_steps_fraction <= 1 or self.first_steps_max < 1:
            raise ConfigError(
                f"first_steps_fraction must be in [0, 1] and first_steps_max >= 1, got {self.first_steps_fraction} "
                f"and {self.first_steps_max}."
            )
        if not self.obs_noise >= 0:
            raise ConfigError(f"obs_noise must be >= 0 (a standard deviation), got {self.obs_noise}.")
        if not self.lr > 0 or (self.warmup_steps is not None and self.warmup_steps < 0):
            raise ConfigError(f"lr must be > 0 and warmup_steps >= 0, got {self.lr} and {self.warmup_steps}.")
        if not self.observed_only_decay >= 0:
            raise ConfigError(f"observed_only_decay must be >= 0 (0 turns it off), got {self.observed_only_decay}.")
        if not 0 <= self.observed_only_dropout < 1:
            raise ConfigError(
                f"observed_only_dropout must be in [0, 1) (0 turns it off), got {self.observed_only_dropout}."
            )
        for name in ("patience", "threads"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ConfigError(f"TrainConfig.{name} must be >= 1 or None, got {getattr(self, name)}.")
        check_seed("--seed", self.seed)

    def for_assignment(self, assignment: Assignment) -> TrainConfig:
        """This config with `gate_lr_scale` filled in with `assignment`'s when it was left None."""
        if self.gate_lr_scale is not None:
            return self
        return replace(self, gate_lr_scale=assignment.gate_lr_scale)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        return cls(**_known(cls, data))


def _known(cls, data: dict) -> dict:
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise ConfigError(f"Unknown {cls.__name__} field(s) {unknown}; known fields are {sorted(names)}.")
    return dict(data)
