"""Which feature files may be used together: one rule on the extractor identity, for every stage.

Trajectory files carry the identity of the extractor that made their features (architecture, feature
width, weights hash, preprocessing, precision; `recordings` stores it, `perception.compatibility_key`
says which fields must match). Training refuses files from different extractors
(`check_identities`), and replay refuses recordings whose features come from another extractor than
the checkpoint's training data (`check_checkpoint_extractor`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from cnep.perception import compatibility_key
from cnep.pipeline.errors import PipelineError, listed
from cnep.recordings import TrajectoryReader

Identity = Mapping[str, str]  # an extractor identity; {} for a motion-only file


def check_identities(identities: Mapping[Path, Identity]) -> dict[str, str]:
    """Require one extractor for all files ({} = motion-only file); raise PipelineError naming the files that differ.

    Files agree when their compatibility keys agree (architecture, feature width, weights hash and
    preprocessing; the backend may differ). Returns the shared identity of the first file.
    """
    groups: dict[tuple[str, ...], list[Path]] = {}
    for path, identity in identities.items():
        groups.setdefault(compatibility_key(identity) if identity else (), []).append(path)
    if len(groups) <= 1:
        return dict(next(iter(identities.values()), {}))
    ordered = sorted(groups.values(), key=len, reverse=True)  # the largest group is the reference
    described = "; ".join(
        f"{len(files)} file(s) {describe(identities[files[0]])}: {listed(files)}" for files in ordered
    )
    raise PipelineError(
        f"trajectory files come from different feature extractors and cannot be mixed: {described}; "
        f"re-extract the odd files with the same --weights (one `cnep extract` run for random "
        f"weights, or --weights with the file saved by --save-weights)"
    )


def check_same_extractor(paths: Sequence[Path]) -> dict[str, str]:
    """Read the extractor identity of trajectory files and require one; returns it ({} if none has features)."""
    identities = {}
    for path in paths:
        with TrajectoryReader(path) as reader:
            identities[Path(path)] = reader.extractor
    return check_identities(identities)


def check_checkpoint_extractor(config_file: Path, trained: Identity, recordings: Mapping[Path, Identity]) -> None:
    """Refuse recordings whose features come from another extractor than a checkpoint's training data.

    config_file: the checkpoint's config.json, which stands for its training files; trained: the extractor
    identity recorded there; recordings: each recording's identity. Only for models that see the features.
    """
    if not trained:
        raise PipelineError(
            f"{config_file}: the model sees image features but the checkpoint names no feature "
            f"extractor, so the recordings' features cannot be checked against its training data; "
            f"train it with `cnep train` (which records the extractor)"
        )
    for path, identity in recordings.items():
        check_identities({config_file: trained, path: identity or {}})


def describe(identity: Identity) -> str:
    """A few words on an identity for an error message: its weights, their hash and the architecture."""
    if not identity:
        return "without features (motion-only)"
    return (
        f"with weights {identity.get('weights', '?')} (sha256 {identity.get('weights_sha256', '?')[:12]}), "
        f"{identity.get('architecture', '?')}"
    )
