"""The assignments: how the loss assigns a context's targets to the experts, one definition each.

`CNEPConfig.assignment` names one; `ASSIGNMENTS[name]` is the whole of what differs between them: the
reconstruction term (`term`, computed by models.loss), the gate's default learning-rate scale, and, for the
expectation-maximisation assignments, how their posterior is balanced over the batch (`Balancing`), from which
follow the step where it settles and whether it reads each sample's whole demonstration. Importable without torch.
A new assignment is one `Assignment` here (and its test); docs/concepts.md says when to choose which.
"""

from __future__ import annotations

from dataclasses import dataclass

from cnep.models.errors import ConfigError

ANNEAL_FRACTION = 0.6  # the EM posterior reaches the mixture's sharpness at this fraction of training

# The reconstruction terms of models.loss.RECONSTRUCTIONS.
GATE_WEIGHTED, MIXTURE, POSTERIOR = "gate-weighted", "mixture", "posterior"


@dataclass(frozen=True)
class Balancing:
    """How an EM assignment balances its posterior over the batch, by the fraction of training done (progress).

    floor, cap: bounds on each expert's share of the batch's mass, as multiples of B/d (models.loss.balanced);
    fade_from, until: fully balanced before `fade_from`, free from `until`; in between the log posterior is
    (1 - s) * balanced + s * free, s rising linearly from 0 to 1 (`free_weight`).
    """

    floor: float
    cap: float
    fade_from: float
    until: float

    def free_weight(self, progress: float) -> float:
        """s at `progress`: 0 while fully balanced, 1 once free."""
        if progress < self.fade_from:
            return 0.0
        if progress >= self.until:
            return 1.0
        return (progress - self.fade_from) / (self.until - self.fade_from)


@dataclass(frozen=True)
class Assignment:
    """One assignment. name: its `CNEPConfig.assignment` value; term: its reconstruction term (GATE_WEIGHTED,
    MIXTURE or POSTERIOR); gate_lr_scale: the gate's learning rate as a fraction of the network's when
    `TrainConfig.gate_lr_scale` is left None; balancing: the EM posterior's balancing (None: no posterior);
    summary: what it does, in a clause (the `--assignment` help)."""

    name: str
    term: str
    gate_lr_scale: float
    summary: str
    balancing: Balancing | None = None

    @property
    def uses_demonstration(self) -> bool:
        """Whether the experts learn from the posterior of each sample's whole demonstration (models.train)."""
        return self.balancing is not None

    @property
    def settled_fraction(self) -> float:
        """The fraction of training from which the posterior is its final one (the balancing has ended): no model
        from before it is kept as the best, since one halfway through the balancing has not yet committed."""
        return self.balancing.until if self.balancing is not None else 0.0


# The gate's learning-rate scale: the paper's and the mixture's terms move the gate by a gradient divided by the
# number of experts (and the mixture's also by the number of values), the EM terms by cross-entropy to the
# posterior at full strength; at the lower scale an EM gate left behaviours sharing an expert (docs/concepts.md).
ASSIGNMENTS: dict[str, Assignment] = {
    a.name: a
    for a in (
        Assignment(
            "paper",
            GATE_WEIGHTED,
            0.3,
            "the paper's gate-weighted NLL (every expert the gate has not ruled out learns every target)",
        ),
        Assignment(
            "mixture",
            MIXTURE,
            0.3,
            "the mixture likelihood (the expert that explains the targets learns them; commits where the context "
            "cannot tell behaviours apart)",
        ),
        Assignment(
            "annealed",
            POSTERIOR,
            1.0,
            "the expert that explains the sample's whole demonstration learns the sample, soft and balanced over the "
            "experts early in training (an idle expert taking a copy of a busy one), as sharp as a mixture's from "
            "60% of the steps on, the gate trained at full strength towards the same choice made from the sample's "
            "own targets",
            Balancing(1.0, 1.0, ANNEAL_FRACTION, ANNEAL_FRACTION),
        ),
        Assignment(
            "bounded",
            POSTERIOR,
            1.0,
            "annealed with each expert's share kept within 0.75-1.5x an equal one instead of equal, faded out over "
            "60-80% of the steps; the best model is kept from where the balancing ends (commits on shared contexts "
            "and keeps the paper's accuracy)",
            Balancing(0.75, 1.5, ANNEAL_FRACTION, 0.8),
        ),
    )
}


def assignment_named(name: str) -> Assignment:
    """The assignment called `name`; a ConfigError naming the known ones otherwise."""
    try:
        return ASSIGNMENTS[name]
    except KeyError:
        raise ConfigError(f"assignment must be one of {', '.join(ASSIGNMENTS)}, got {name!r}.") from None
