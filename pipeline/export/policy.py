"""A checkpoint as a `runtime.Policy` on torch: the CNEP of `cnep train` and the extractor its features came from.

    policy = checkpoint_policy("checkpoints/cnep", extractor="extractor.pt")

The spec (how an observation becomes a model row, the normaliser, the time base) is built here from the
checkpoint's config.json, and `cnep export` writes this same spec into its manifest, so the torch policy
and the exported one read observations alike. The extractor must be the one the training features came
from (same weights hash, architecture and preprocessing), else the policy is refused.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cnep.models.checkpoint import CONFIG_FILE
from cnep.models.online import TorchNetwork, model_columns
from cnep.perception import FeatureExtractor
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.identity import check_identities
from cnep.pipeline.train.checkpoint import TrainedModel, load_trained
from cnep.pipeline.train.constants import IMAGE_KEY, IMAGE_SIZE, MAX_STEP, RECIPE, TASKS
from cnep.recordings.constants import BLOCK_FEATURES, BLOCK_GRIPPER, BLOCKS_MOTION
from cnep.runtime import DEFAULT_WAYPOINTS, ConditioningPolicy, GripperCommand, Policy, PolicySpec, TimeBase

IMAGENET_PREFIX = "imagenet:"  # extractor identities of ImageNet weights name them so (perception.weights)


@dataclass(frozen=True)
class LoadedCheckpoint:
    """A checkpoint (its model, columns and config), its spec and its extractor (None for a model without a
    camera)."""

    trained: TrainedModel
    spec: PolicySpec
    extractor: FeatureExtractor | None


def load_for_policy(
    checkpoint: str | Path, extractor: str | Path | None = None, backend: str = "auto", threads: int | None = None
) -> LoadedCheckpoint:
    """Load the checkpoint folder `checkpoint` and, if its model sees the camera, its extractor.

    extractor: the weights file the training features were made with (`cnep extract --save-weights`, the demo's
    `extractor.pt`); None for ImageNet weights (found as `cnep extract` finds them). backend, threads: the
    extractor's (perception.FeatureExtractor).
    """
    trained = load_trained(checkpoint)
    spec = policy_spec(trained)
    features = None
    if spec.features is not None:
        features = feature_extractor(trained.path, trained.config.get("extractor") or {}, extractor, backend, threads)
    return LoadedCheckpoint(trained, spec, features)


def checkpoint_policy(
    checkpoint: str | Path,
    extractor: str | Path | None = None,
    *,
    backend: str = "auto",
    threads: int | None = None,
    waypoints: int = DEFAULT_WAYPOINTS,
    conditioning: ConditioningPolicy | None = None,
    time_base: TimeBase | None = None,
    gripper: GripperCommand | None = None,
    camera: str | None = None,
) -> Policy:
    """The checkpoint folder `checkpoint` as a Policy on torch (see `load_for_policy` and `runtime.Policy`)."""
    loaded = load_for_policy(checkpoint, extractor, backend, threads)
    return Policy(
        TorchNetwork(loaded.trained.model),
        loaded.spec,
        loaded.extractor.features if loaded.extractor is not None else None,
        waypoints=waypoints,
        conditioning=conditioning,
        time_base=time_base,
        gripper=gripper,
        camera=camera,
    )


def policy_spec(trained: TrainedModel) -> PolicySpec:
    """The spec of the checkpoint's model: its row's features block and state blocks, normaliser, time base and
    gripper command (a checkpoint without one, or a model without the gripper block, has none), the tasks and the
    camera it was trained on, its conditioning, the demonstrations' largest steps and the recipe it was trained with
    (a checkpoint written before they were stored: none, any camera, the default conditioning, no bound)."""
    model, blocks, config = trained.model, trained.mapping.blocks, trained.config
    state = tuple((BLOCKS_MOTION[name], blocks[name]) for name in BLOCKS_MOTION if name in blocks)
    time_base, gripper = config.get("time_base"), config.get("gripper")
    sees = BLOCK_FEATURES in blocks
    try:
        return PolicySpec(
            columns=model_columns(model),
            n_experts=model.n_experts,
            features=blocks.get(BLOCK_FEATURES),
            state=state,
            time_base=TimeBase.from_dict(time_base) if time_base else None,
            gripper=GripperCommand.from_dict(gripper) if gripper and BLOCK_GRIPPER in blocks else None,
            expert_labels=labels_by_expert(trained.expert_labels, model.n_experts),
            tasks=tuple(config.get(TASKS) or ()),
            image_key=config.get(IMAGE_KEY) if sees else None,
            image_size=tuple(config[IMAGE_SIZE]) if sees and config.get(IMAGE_SIZE) else None,
            conditioning=trained.conditioning,
            max_step=config.get(MAX_STEP),
            recipe={key: config[key] for key in RECIPE if key in config} or None,
        )
    except (ValueError, TypeError) as exc:
        raise PipelineError(f"{trained.path / CONFIG_FILE}: cannot be run as a policy: {exc}") from None


def labels_by_expert(labels: dict[int, str], n_experts: int) -> tuple[str, ...]:
    """`labels` (expert -> label) as one entry per expert ("" for an expert without one), () when there are none."""
    return tuple(labels.get(expert, "") for expert in range(n_experts)) if labels else ()


def feature_extractor(
    checkpoint: Path, trained: dict[str, str], weights: str | Path | None, backend: str, threads: int | None
) -> FeatureExtractor:
    """The extractor of the checkpoint's training features, from `weights` (None: ImageNet), checked against them."""
    config_file = checkpoint / CONFIG_FILE
    name = trained.get("weights", "")
    weights = None if str(weights) == "imagenet" else weights
    if trained.get("precision", "fp32") != "fp32":
        raise PipelineError(
            f"{config_file}: the model was trained on {trained['precision']} features; a policy runs the fp32 "
            f"extractor (and `cnep export --int8` its int8 graph): train on fp32 features"
        )
    if weights is None and not name.startswith(IMAGENET_PREFIX):
        raise PipelineError(
            f"{config_file}: the training features were made with weights {name or '(unnamed)'} (sha256 "
            f"{trained.get('weights_sha256', '?')[:12]}); give that weights file with --extractor (`cnep extract "
            f"--save-weights` writes one, the demo saves OUT/extractor.pt)"
        )
    if weights is not None and not Path(weights).is_file():
        raise PipelineError(f"{weights}: no such weights file; give the file the training features were made with")
    extractor = FeatureExtractor("imagenet" if weights is None else weights, backend=backend, threads=threads)
    check_identities({config_file: trained, Path(weights or extractor.weights_name): extractor.identity})
    return extractor
