"""The ridge probe the examples share: how well a linear read of some rows predicts positions on rows it never saw.

from probes import probe   # (an example's own folder is on the import path when it runs)
"""

from __future__ import annotations

import numpy as np

LAMBDAS = 10.0 ** np.arange(-1, 7)  # the ridge penalties cross-validation chooses from
FOLDS = 5


def ridge(x: np.ndarray, y: np.ndarray, fit: np.ndarray, test: np.ndarray, lam: float) -> np.ndarray:
    """Rows `test` of y (m, d) predicted by ridge regression on x (m, f) fitted on rows `fit` (standardised with
    their mean and std; dual form, as the rows are fewer than the columns)."""
    mean, std = x[fit].mean(0), x[fit].std(0) + 1e-6
    z = (x - mean) / std  # (m, f)
    offset = y[fit].mean(0)
    weights = np.linalg.solve(z[fit] @ z[fit].T + lam * np.eye(len(fit)), y[fit] - offset)  # (k, d)
    return z[test] @ z[fit].T @ weights + offset


def probe(x: np.ndarray, y: np.ndarray, k: int) -> dict:
    """The ridge probe of y (m, 2) m from x (m, f) fitted on the first k rows, lambda by FOLDS-fold cross-validation
    there, scored on the rest: median errors (cm) of the probe and of the fitting rows' mean, and the lambda."""
    rows, test = np.arange(k), np.arange(k, len(x))

    def cv_error(lam: float) -> float:
        errors = [
            np.linalg.norm(ridge(x, y, np.setdiff1d(rows, fold), fold, lam) - y[fold], axis=1)
            for fold in np.array_split(rows, FOLDS)
        ]
        return float(np.median(np.concatenate(errors)))

    lam = min(LAMBDAS, key=cv_error)
    error = np.linalg.norm(ridge(x, y, rows, test, lam) - y[test], axis=1)
    mean_error = np.linalg.norm(y[:k].mean(0) - y[test], axis=1)
    return {
        "probe_cm": round(100 * float(np.median(error)), 2),
        "mean_cm": round(100 * float(np.median(mean_error)), 2),
        "lambda": float(lam),
    }
