"""The columns a model observes but does not predict, as the encoder reads them: their top principal components.

A camera's 1280 image features per frame, over a few dozen demonstrations, vary along a handful of directions; an
encoder reading all of them can tell its training scenes apart by what varies in none of the others.
`CNEPConfig.feature_components` = K has it read instead the rows' coordinates along the K directions of most
variance of those columns, normalised, over the training rows, each scaled to unit variance there
(`CNEP.feature_projection`): the whitened principal components of their correlation matrix. Directions of the
normalised columns weigh every feature alike, whatever its spread; unit variance gives each component the scale of
the other inputs.

The projection is fitted from the training rows' `Moments` (their mean and the scatter matrix of those columns), so
that it is the same whether the rows were read at once or in shares on several processes, and it acts on the
normalised values the encoder receives (the normaliser's `(x - loc) / scale`).
"""

from __future__ import annotations

import numpy as np

from cnep.models.errors import ConfigError
from cnep.models.normaliser import Moments

# A direction whose variance over the training rows is below this share of the largest's holds only rounding noise:
# it is not scaled up to unit variance (as the normaliser leaves a constant column's scale at 1).
FLAT_VARIANCE = 1e-10


def principal_projection(moments: Moments, scale: np.ndarray, components: int) -> np.ndarray:
    """(len(moments.co), K) float64: the normalised values (R, len(co)) of the columns `moments.co` times this are
    the rows' coordinates along the K principal directions of those normalised values over the rows `moments`
    describes, largest variance first, each with unit variance over those rows.

    scale: (len(co),) the normaliser's scale of those columns. Each direction's sign puts its entry of largest
    magnitude positive, so the same rows always give the same projection.
    """
    n = len(moments.co)
    if moments.scatter is None or not 1 <= components <= n:
        raise ConfigError(
            f"A projection onto {components} principal components needs the scatter matrix of at least that many "
            f"columns; the moments carry it for {n}."
        )
    scale = np.asarray(scale, dtype=np.float64)
    covariance = moments.scatter / (moments.count * np.outer(scale, scale))  # (n, n) of the normalised values
    variance, directions = np.linalg.eigh(covariance)  # ascending
    variance = variance[::-1][:components].clip(min=0.0)  # (K,)
    directions = directions[:, ::-1][:, :components]  # (n, K)
    largest = np.abs(directions).argmax(axis=0)  # (K,)
    directions = directions * np.sign(directions[largest, np.arange(components)])
    flat = variance <= FLAT_VARIANCE * max(variance[0], np.finfo(np.float64).tiny)
    return directions / np.where(flat, 1.0, np.sqrt(variance))  # (n, K)
