"""Perception: RGB frames (numpy, any size) -> 1280-d MobileNet-v2 features (numpy). See docs/concepts.md."""

import importlib

# Module -> the public names it defines. A name's module is imported when the name is first used (PEP 562), as in
# cnep.models: which features go together (`compatibility_key`) is read without loading torch and torchvision.
_MODULES = {
    "backends": ("available_backends",),
    "constants": ("FEATURE_DIM", "IMAGE_SIZE"),
    "errors": ("PerceptionError",),
    "extractor": ("FeatureExtractor",),
    "frames": ("decode_image", "resize_frames"),
    "identity": ("compatibility_key",),
    "weights": ("find_imagenet_weights", "resolve_weights", "state_dict_sha256"),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> object:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
