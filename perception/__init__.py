"""Perception: RGB frames (numpy, any size) -> 1280-d MobileNet-v2 features (numpy). See docs/concepts.md."""

from cnep.perception.backends import available_backends
from cnep.perception.constants import FEATURE_DIM, IMAGE_SIZE
from cnep.perception.errors import PerceptionError
from cnep.perception.extractor import FeatureExtractor, compatibility_key
from cnep.perception.frames import decode_image, resize_frames
from cnep.perception.weights import find_imagenet_weights, resolve_weights, state_dict_sha256

__all__ = [
    "FEATURE_DIM",
    "IMAGE_SIZE",
    "FeatureExtractor",
    "PerceptionError",
    "available_backends",
    "compatibility_key",
    "decode_image",
    "find_imagenet_weights",
    "resize_frames",
    "resolve_weights",
    "state_dict_sha256",
]
