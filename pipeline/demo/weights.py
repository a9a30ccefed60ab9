"""Which weights the demo extracts features with: ImageNet's wherever they can be had, seeded random ones otherwise.

`auto` looks for MobileNet-v2's ImageNet weights as `cnep extract --weights imagenet` does (perception.weights:
$CNEP_MOBILENET_WEIGHTS, the torch hub cache, else a download into it unless downloading is off) and, when they
cannot be had, falls back to seeded random weights with one warning that says why and how to get them. `imagenet`
raises that PerceptionError instead; `random` and a file are taken as given (a file is loaded once here, so a wrong
one is refused before the demo generates anything).
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

from cnep.perception import PerceptionError, find_imagenet_weights, resolve_weights
from cnep.perception.constants import CONNECT_TIMEOUT_S, WEIGHTS_ENV_VAR
from cnep.perception.weights import hub_checkpoints
from cnep.perception.weights import offline as offline_by_environment
from cnep.pipeline.demo.config import AUTO_WEIGHTS, IMAGENET_WEIGHTS, RANDOM_WEIGHTS

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class WeightsChoice:
    """weights: what the extract stage is given (`imagenet`, `random` or a path); imagenet_unavailable: why the
    features are not ImageNet's, when `auto` fell back to random weights (None otherwise)."""

    weights: str
    imagenet_unavailable: str | None = None


def choose_weights(spec: str, offline: bool = False) -> WeightsChoice:
    """The weights for `spec` (`auto`, `imagenet`, `random` or a state-dict path); `offline`: never download
    ImageNet weights (as CNEP_OFFLINE does). Raises PerceptionError for `imagenet` that cannot be had and for a file
    that is missing or not a MobileNet-v2 state dict."""
    if spec == RANDOM_WEIGHTS:
        return WeightsChoice(RANDOM_WEIGHTS)
    if spec not in (AUTO_WEIGHTS, IMAGENET_WEIGHTS):
        resolve_weights(spec)
        return WeightsChoice(spec)
    download = not (offline or offline_by_environment())
    explicit = os.environ.get(WEIGHTS_ENV_VAR)  # a file named there is used, never downloaded
    if download and not explicit:
        log.info(
            "looking for ImageNet weights in %s, else downloading them there (without a network this gives up within "
            "%.0f s; --offline skips it)",
            hub_checkpoints(),
            CONNECT_TIMEOUT_S,
        )
    try:
        found = find_imagenet_weights(download=download)
    except PerceptionError as exc:
        if spec == IMAGENET_WEIGHTS:
            raise
        why = (
            f"{WEIGHTS_ENV_VAR} is not a file"
            if explicit
            else f"none in the torch hub cache and {'the download failed' if download else 'downloading is off'}"
        )
        log.warning("the features come from seeded random weights, not ImageNet's: %s", exc)
        return WeightsChoice(RANDOM_WEIGHTS, why)
    log.info("the features come from ImageNet weights: %s", found)
    return WeightsChoice(IMAGENET_WEIGHTS)
