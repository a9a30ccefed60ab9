"""The evaluation's three protocols on trajectories `(T, dy)`: which queries each draws, and how a method scores.

- paper (`paper_queries`, `score`): the paper's table "MSE over generated trajectories when conditioned from
  intermediate points": an intermediate point where two modes come close and the end point of a demonstration of
  one of them; scored by the true MSE (and MAE) against the ground truth and by mode accuracy;
- held-out (`heldout_queries`): the same kind of points from demonstrations the model never saw, scored against
  them: generalisation rather than mode picking;
- commitment (`shared_queries`, `commitment`): one point that two or more modes share and nothing else, so any one
  of those modes is right and their average wrong.

Every drawn paper or held-out query must be decisive (`_decisive`); other draws are discarded. How these differ from
the authors' notebooks: docs/concepts.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

# A method: (obs_t (n,), obs_y (n, dy), query_t (T,)) -> generated (T, dy)
Generate = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]

NOISE = 0.02  # std of the noise on the intermediate point, as a fraction of the data's range
CLOSE = 0.05  # steps whose mode gap is within this fraction of the range of the smallest count as "close"
SEPARATION = 0.1  # two modes are told apart by their end points when these differ by this fraction of the range
DECISIVE = 4.0  # a query's mode must be this many times nearer (squared distance) than any other mode
ATTEMPTS = 100  # draws per query before giving up on finding a decisive one
BAND_SIGMAS = 3.0  # commitment: a valid trajectory stays within this many within-mode stds of one demonstration


@dataclass(frozen=True)
class Query:
    obs_t: np.ndarray  # (2,) intermediate time, 1.0
    obs_y: np.ndarray  # (2, dy)
    truth: np.ndarray  # (T, dy)
    mode: int  # mode of the ground truth


def _times(T: int) -> np.ndarray:
    return np.arange(T) / (T - 1)


def _close_steps(demos: np.ndarray, modes: np.ndarray, a: int, b: int) -> np.ndarray:
    """Interior steps where the mean trajectories of modes a and b come closest."""
    T = demos.shape[1]
    gap = np.linalg.norm(demos[modes == a].mean(0) - demos[modes == b].mean(0), axis=-1)  # (T,)
    interior = np.arange(T // 20, T - T // 20)
    span = np.ptp(demos)
    g = gap[interior]
    return interior[g <= g.min() + CLOSE * span]


def _separable_partners(demos: np.ndarray, modes: np.ndarray) -> dict[int, np.ndarray]:
    """For each mode, the other modes whose mean end points differ from its own by `SEPARATION`."""
    labels = np.unique(modes)
    ends = {k: demos[modes == k, -1].mean(0) for k in labels}
    limit = SEPARATION * np.ptp(demos)
    return {a: np.array([b for b in labels if b != a and np.linalg.norm(ends[a] - ends[b]) > limit]) for a in labels}


def _decisive(pool: np.ndarray, pool_modes: np.ndarray, steps: np.ndarray, obs_y: np.ndarray, mode: int) -> bool:
    """Whether points `obs_y` at `steps` name `mode`: its nearest demonstration is `DECISIVE` times nearer
    (squared distance) than any other mode's, and `DECISIVE` times likelier under the protocol's noise (Gaussian,
    std `NOISE` of the range). The first rules out a third mode passing through a crossing and sharing the end
    point of one of the pair; the second, demonstrations of two modes both passing within a fraction of the noise
    of both points (the ratio of two tiny distances can be large while the noise alone picks the truth)."""
    dist = ((pool[:, steps] - obs_y) ** 2).sum((1, 2))  # (N,)
    others = dist[pool_modes != mode]
    if others.size == 0:
        return True
    own, other = dist[pool_modes == mode].min(), others.min()
    noise_var = (NOISE * np.ptp(pool)) ** 2
    # under Gaussian noise the two nearest differ in likelihood by exp((other - own) / (2 noise_var))
    return bool(other >= DECISIVE * own and other - own >= 2 * noise_var * np.log(DECISIVE))


def _draw(draw: Callable[[], Query | None], n: int, what: str) -> list[Query]:
    """`n` queries from `draw`, which returns None for a draw that is not decisive."""
    queries: list[Query] = []
    for _ in range(n * ATTEMPTS):
        q = draw()
        if q is not None:
            queries.append(q)
            if len(queries) == n:
                return queries
    raise ValueError(f"only {len(queries)} of {n} {what} queries were decisive after {n * ATTEMPTS} draws")


def paper_queries(demos: np.ndarray, modes: np.ndarray, n: int = 50, seed: int = 0) -> list[Query]:
    """`n` queries on a demonstration pool `(N, T, dy)` with mode labels `(N,)`.

    Each conditions on an intermediate point where two modes come close (plus noise) and on the end point (t = 1)
    of a demonstration of one of those two modes. Only pairs of modes whose end points differ (by `SEPARATION` of
    the data's range) are used: where two modes also end at the same place (modes 2 and 3 of the 4-mode set), the
    two points cannot tell them apart and the "right" mode is a coin flip. The ground truth is the training
    demonstration closest to the two conditioning points (as the paper states); the authors' notebooks instead
    chose the one closest to the *generated* trajectory.
    """
    rng = np.random.default_rng(seed)
    T, span = demos.shape[1], np.ptp(demos)
    partners = _separable_partners(demos, modes)
    pairs = [(a, b) for a, bs in partners.items() for b in bs if a < b]

    def draw() -> Query | None:
        if not pairs:  # one mode (or none separable): any interior point
            a = b = modes[0]
            step = int(rng.integers(T // 20, T - T // 20))
        else:
            a, b = pairs[rng.integers(len(pairs))]
            step = int(rng.choice(_close_steps(demos, modes, a, b)))
        middle = 0.5 * (demos[modes == a, step].mean(0) + demos[modes == b, step].mean(0))
        middle = middle + NOISE * span * rng.standard_normal(middle.shape)
        end_demo = demos[rng.choice(np.flatnonzero(modes == rng.choice([a, b])))]
        obs_y = np.stack([middle, end_demo[-1]])  # (2, dy)
        steps = np.array([step, T - 1])
        truth = int(((demos[:, steps] - obs_y) ** 2).sum((1, 2)).argmin())
        if not _decisive(demos, modes, steps, obs_y, modes[truth]):
            return None
        return Query(steps / (T - 1), obs_y, demos[truth], int(modes[truth]))

    return _draw(draw, n, "paper")


def heldout_queries(
    pool: np.ndarray, pool_modes: np.ndarray, unseen: np.ndarray, unseen_modes: np.ndarray, n: int = 50, seed: int = 0
) -> list[Query]:
    """Conditioning points (near a crossing of the demo's mode with another, and the end) of unseen demos, kept
    only where they name the unseen demonstration's own mode among the pool's demonstrations (`_decisive`)."""
    rng = np.random.default_rng(seed)
    T = unseen.shape[1]
    partners = _separable_partners(pool, pool_modes)

    def draw() -> Query | None:
        i = int(rng.integers(len(unseen)))
        a = unseen_modes[i]
        if len(partners[a]) == 0:
            step = int(rng.integers(T // 20, T - T // 20))
        else:
            b = rng.choice(partners[a])
            step = int(rng.choice(_close_steps(pool, pool_modes, a, b)))
        steps = np.array([step, T - 1])
        obs_y = unseen[i, steps]
        if not _decisive(pool, pool_modes, steps, obs_y, a):
            return None
        return Query(steps / (T - 1), obs_y, unseen[i], int(a))

    return _draw(draw, n, "held-out")


def score(generate: Generate, queries: list[Query], pool: np.ndarray, pool_modes: np.ndarray) -> dict[str, float]:
    """MSE and MAE over the whole generated trajectory against each query's truth (mean and std over queries) and
    mode accuracy (the generated trajectory is nearest, in MSE, to a training demonstration of the truth's mode)."""
    T = pool.shape[1]
    mse, mae, hits = [], [], []
    for q in queries:
        out = np.asarray(generate(q.obs_t, q.obs_y, _times(T)), dtype=np.float64).reshape(q.truth.shape)
        mse.append(np.mean((out - q.truth) ** 2))
        mae.append(np.mean(np.abs(out - q.truth)))
        nearest = int(((pool - out) ** 2).mean((1, 2)).argmin())
        hits.append(pool_modes[nearest] == q.mode)
    return {
        "mse": float(np.mean(mse)),
        "mse_std": float(np.std(mse)),
        "mae": float(np.mean(mae)),
        "mae_std": float(np.std(mae)),
        "mode_accuracy": float(np.mean(hits)),
    }


@dataclass(frozen=True)
class SharedQuery:
    """A commitment query: one point that the listed modes' mean trajectories share."""

    obs_t: np.ndarray  # (1,) time of the point
    obs_y: np.ndarray  # (1, dy)
    modes: tuple[int, ...]  # the modes whose mean passes within the band of the point (at least 2)


def within_mode_band(demos: np.ndarray, modes: np.ndarray) -> float:
    """`BAND_SIGMAS` x the within-mode standard deviation of a pool `(N, T, dy)`: the root of the mean, over
    modes, steps and output dims, of the variance across the mode's demonstrations."""
    variances = [demos[modes == k].var(0).mean() for k in np.unique(modes)]
    return float(BAND_SIGMAS * np.sqrt(np.mean(variances)))


def shared_queries(demos: np.ndarray, modes: np.ndarray) -> list[SharedQuery]:
    """Every point where two or more modes meet, once, in time order, on a pool `(N, T, dy)` with labels `(N,)`.

    For each pair of modes, each run of steps where their mean trajectories stay within the band of each
    other (a crossing, a stretch they share, a shared start or end) gives one point: the midpoint of
    the two means at the run's closest step. Points within two steps and one band of an earlier point
    are the same point.
    """
    T, band = demos.shape[1], within_mode_band(demos, modes)
    labels = np.unique(modes)
    means = np.stack([demos[modes == k].mean(0) for k in labels])  # (K, T, dy)
    found: list[tuple[int, np.ndarray]] = []
    for i in range(len(labels)):
        for b in range(i + 1, len(labels)):
            gap = np.linalg.norm(means[i] - means[b], axis=-1)  # (T,)
            close = np.concatenate([[False], gap <= band, [False]]).astype(int)
            starts, stops = np.flatnonzero(np.diff(close) == 1), np.flatnonzero(np.diff(close) == -1)
            for start, stop in zip(starts, stops):  # each run of steps where the two means stay within the band
                k = start + int(gap[start:stop].argmin())
                found.append((k, 0.5 * (means[i, k] + means[b, k])))
    queries: list[tuple[int, np.ndarray]] = []
    for step, y in sorted(found, key=lambda f: f[0]):
        if not any(abs(step - s) <= 2 and np.linalg.norm(y - z) <= band for s, z in queries):
            queries.append((step, y))
    out = []
    for step, y in queries:
        near = tuple(int(k) for k, m in zip(labels, means) if np.linalg.norm(m[step] - y) <= band)
        out.append(SharedQuery(np.array([step / (T - 1)]), y[None].copy(), near))
    return out


def commitment_scores(
    generated: np.ndarray, queries: list[SharedQuery], pool: np.ndarray, pool_modes: np.ndarray
) -> dict[str, np.ndarray]:
    """Per query: generated `(Q, T, dy)` against the pool `(N, T, dy)`.

    Returns "mse" and "max_deviation" (each minimised over the demonstrations), "valid" (bool: within the band,
    `within_mode_band`, of one demonstration at every step, that demonstration itself passing within the band of
    the conditioning point) and "mode" (the mode of the demonstration nearest in max deviation; -1 for a
    non-finite trajectory).
    """
    band = within_mode_band(pool, pool_modes)
    T = pool.shape[1]
    deviation = np.linalg.norm(generated[:, None] - pool[None], axis=-1)  # (Q, N, T)
    deviation = np.where(np.isfinite(deviation), deviation, np.inf)
    steps = np.array([int(round(q.obs_t[0] * (T - 1))) for q in queries])  # (Q,)
    at_point = np.linalg.norm(
        pool[:, steps].transpose(1, 0, 2) - np.stack([q.obs_y[0] for q in queries])[:, None], axis=-1
    )  # (Q, N): each demonstration's distance from the query's point
    worst = deviation.max(-1)  # (Q, N)
    nearest = worst.argmin(-1)  # (Q,)
    consistent = np.where(at_point <= band, worst, np.inf)  # only demonstrations through the point count
    return {
        "mse": (deviation**2).mean(-1).min(-1) / generated.shape[-1],
        "max_deviation": worst.min(-1),
        "valid": consistent.min(-1) <= band,
        "mode": np.where(np.isfinite(worst.min(-1)), pool_modes[nearest], -1),
    }


def commitment(
    generate: Generate, queries: list[SharedQuery], pool: np.ndarray, pool_modes: np.ndarray
) -> dict[str, float]:
    """One method on the commitment queries: mean MSE and max deviation (std over the queries with a finite
    output), valid share (of all queries), the band, and the number of non-finite outputs."""
    T = pool.shape[1]
    generated = np.stack(
        [np.asarray(generate(q.obs_t, q.obs_y, _times(T)), dtype=np.float64).reshape(T, -1) for q in queries]
    )  # (Q, T, dy)
    s = commitment_scores(generated, queries, pool, pool_modes)
    finite = np.isfinite(s["max_deviation"])  # a non-finite trajectory is invalid and counted as a failure
    mse, worst = s["mse"][finite], s["max_deviation"][finite]
    nan = float("nan")
    return {
        "mse": float(mse.mean()) if finite.any() else nan,
        "mse_std": float(mse.std()) if finite.any() else nan,
        "max_deviation": float(worst.mean()) if finite.any() else nan,
        "max_deviation_std": float(worst.std()) if finite.any() else nan,
        "valid": float(s["valid"].mean()),
        "queries": len(queries),
        "band": within_mode_band(pool, pool_modes),
        "failures": int((~finite).sum()),
    }
