"""Baselines of the paper's comparison, behind one interface: `fit(demos)` then `generate(obs_t, obs_y, query_t)`.

- `ProMP`: probabilistic movement primitives from `movement_primitives` (imitate, then condition on
  each observed point).
- `GMMGMR`: a Gaussian mixture over whole trajectories from `gmr`, conditioned on the observed time
  steps (with or without a covariance ridge).
- `NearestDemo`: the training demonstration closest to the conditioning points (a sanity line: on the
  paper's protocol it scores almost 0).

`BaselineNetwork` runs a fitted method as the runtime's `Network`, inside a `runtime.Policy` (a closed loop's
policy), on the rows a `Reduction` makes; `ReducedNetwork` runs a network trained on those rows (a CNEP on the
same inputs) as one of the full rows.

Demonstrations are `(N, T, dy)` arrays sampled at times `k / (T - 1)`; `generate` returns `(m, dy)` at
the query times (linear interpolation between the demonstration's steps). ProMP and GMM-GMR need the
optional extra: `pip install .[baselines]`; their libraries are imported only when fitting.
"""

from cnep.models.baselines.base import Method
from cnep.models.baselines.gmm import GMMGMR
from cnep.models.baselines.nearest import NearestDemo
from cnep.models.baselines.network import BaselineNetwork, ReducedNetwork, Reduction
from cnep.models.baselines.promp import ProMP

__all__ = ["GMMGMR", "BaselineNetwork", "Method", "NearestDemo", "ProMP", "ReducedNetwork", "Reduction"]
