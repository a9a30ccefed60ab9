"""The `cnep` policy type's processors (LeRobot finds `make_cnep_pre_post_processors` by the type's name): the batch
moved to the CPU, where the runtime reads it, and nothing normalised, since the exported policy carries its own
normaliser."""

from __future__ import annotations

from typing import Any

from lerobot.processor import DeviceProcessorStep, PolicyAction, PolicyProcessorPipeline
from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action
from lerobot.utils.constants import POLICY_POSTPROCESSOR_DEFAULT_NAME, POLICY_PREPROCESSOR_DEFAULT_NAME

from lerobot_policy_cnep.configuration_cnep import CNEPConfig


def make_cnep_pre_post_processors(
    config: CNEPConfig, dataset_stats: dict | None = None
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]], PolicyProcessorPipeline[PolicyAction, PolicyAction]
]:
    """(preprocessor, postprocessor); `dataset_stats` is not read: the policy folder holds its normaliser."""
    return (
        PolicyProcessorPipeline[dict[str, Any], dict[str, Any]](
            steps=[DeviceProcessorStep(device="cpu")], name=POLICY_PREPROCESSOR_DEFAULT_NAME
        ),
        PolicyProcessorPipeline[PolicyAction, PolicyAction](
            steps=[DeviceProcessorStep(device="cpu")],
            name=POLICY_POSTPROCESSOR_DEFAULT_NAME,
            to_transition=policy_action_to_transition,
            to_output=transition_to_policy_action,
        ),
    )
