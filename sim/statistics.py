"""The statistics of a closed-loop table: a rate's 95% interval (`wilson`) and the diversity of what the successful
episodes did (`behaviour_entropy`).

Behaviour entropy follows D3IL (Jia et al., "Towards Diverse Behaviors: A Benchmark for Imitation Learning with
Human Demonstrations", ICLR 2024, and its simulation code): only the successful rollouts count; the behaviours'
shares give an entropy in natural log divided by the log of the number of possible behaviours (every behaviour
the task allows, used or not), so it lies in [0, 1]; where the scene limits the choice, the entropy of the
behaviours within each scene context, averaged over the contexts with equal weight, contexts without a successful
rollout left out. D3IL repeats each test scene; here every episode's scene is its own, so a context is what the
scene leaves open (the valid behaviours), and it normalises each context by its own number of valid behaviours. A
context with one valid behaviour leaves no choice: it has no entropy and is left out; with no context left, the
entropy is not defined (None).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Hashable, Iterable

Z95 = 1.959963984540054  # the standard normal's 97.5% quantile: a two-sided 95% interval


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval (lower, upper) of a share of `successes` out of `n` (>= 1) trials, at the normal
    quantile `z` (95% by default); within [0, 1], 0 the lower bound of 0/n and 1 the upper of n/n."""
    if n < 1 or not 0 <= successes <= n:
        raise ValueError(f"a share needs 0 <= successes <= n and n >= 1, got {successes}/{n}")
    p, z2 = successes / n, z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    return (0.0 if successes == 0 else centre - half, 1.0 if successes == n else centre + half)


def normalised_entropy(behaviours: Iterable[Hashable], possible: int) -> float:
    """The entropy of the shares of `behaviours` (at least one), over log(`possible`) (>= 2, the behaviours that
    could have been chosen): 0 for one behaviour, 1 for all `possible` equally often."""
    counts = Counter(behaviours)
    if not counts or possible < 2 or len(counts) > possible:
        raise ValueError(f"an entropy needs behaviours among >= 2 possible ones, got {dict(counts)} of {possible}")
    n = sum(counts.values())
    return -sum(c / n * math.log(c / n) for c in counts.values()) / math.log(possible)


def behaviour_entropy(choices: Iterable[tuple[tuple[Hashable, ...], Hashable]]) -> float | None:
    """The behaviour entropy (module docstring) of successful episodes, each `(valid, behaviour)`: the behaviours
    its scene left open (the context) and the one it took; to 4 decimals, None where no context left a choice.
    Raises ValueError for a behaviour outside its context's valid ones."""
    contexts: dict[tuple[Hashable, ...], list[Hashable]] = {}
    for valid, behaviour in choices:
        if len(valid) < 2:
            continue
        if behaviour not in valid:
            raise ValueError(f"behaviour {behaviour!r} is not one of its scene's valid {valid}")
        contexts.setdefault(tuple(sorted(valid, key=str)), []).append(behaviour)
    if not contexts:
        return None
    return round(sum(normalised_entropy(b, len(valid)) for valid, b in contexts.items()) / len(contexts), 4)
