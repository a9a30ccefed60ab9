"""The torch-free runtime: a trained policy in a robot's control loop, on numpy, ONNX Runtime and OpenCV.

    from cnep.runtime import load_policy
    policy = load_policy("policy/")        # a folder written by `cnep export`
    policy.reset()
    action = policy.select_action({"observation.images.front": frame, "observation.state": state})

This package imports nothing else of cnep and never torch (tests/test_architecture.py checks it): a robot
installs it alone with `pip install policy/runtime` (docs/how-to/run-a-policy.md). The conditioning logic
(`Conditioner`) is shared with the torch model (models.online), so both backends decide alike.
"""

import importlib

# Module -> the public names it defines. A name's module is imported when the name is first used (PEP 562), so
# `cnep.runtime.spans` (which the models' config reads) loads neither OpenCV nor ONNX Runtime.
_MODULES = {
    "conditioning": ("Columns", "Conditioner", "ConditioningPolicy", "ExpertSwitch", "Network", "hand_over"),
    "constants": ("DEFAULT_WAYPOINTS", "IMAGE_KEY_PREFIX", "STATE_KEY", "TIMESTAMP_KEY"),
    "errors": ("PolicyError",),
    "exported": ("ExportedNetwork", "load_policy"),
    "gripper": ("GripperCommand",),
    "manifest": ("Manifest", "read_manifest"),
    "policy": ("Policy", "PolicyStep"),
    "spec": ("STATE_NAMES", "PolicySpec"),
    "timebase": ("TimeBase",),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> object:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
