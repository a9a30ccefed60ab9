"""Perception: RGB frames (numpy, any size) -> 1280-d MobileNet-v2 features (numpy). See docs/perception.md."""

from perception.backends import available_backends
from perception.constants import FEATURE_DIM, IMAGE_SIZE
from perception.errors import PerceptionError
from perception.extractor import FeatureExtractor, compatibility_key
from perception.frames import decode_image, resize_frames
from perception.weights import find_imagenet_weights, resolve_weights, state_dict_sha256

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
