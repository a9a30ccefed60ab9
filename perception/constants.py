"""Constants of the feature extractor: sizes, normalisation, weight file names, backend order."""

from __future__ import annotations

from cnep.runtime.constants import IMAGE_SIZE  # frames are resized to IMAGE_SIZE x IMAGE_SIZE before the network

FEATURE_DIM = 1280  # width of one feature vector (channels of the last MobileNet-v2 block)
FEATURE_GRID = 7  # the last block's map is FEATURE_GRID x FEATURE_GRID cells (224 / 32)
# How the last block's (1280, 7, 7) map becomes 1280 numbers, and the architecture each pooling writes into the
# extractor identity. `global`: every channel averaged over the whole map (what ImageNet weights were trained
# with). `cells`: channel c read at cell c mod 49 only, so the 1280 numbers keep where things are (the pooling of
# seeded random weights, whose channels carry no meaning of their own; see perception.network).
ARCHITECTURES = {
    "global": "torchvision.mobilenet_v2.features+global_avg_pool",
    "cells": f"torchvision.mobilenet_v2.features+cell_pool_{FEATURE_GRID}x{FEATURE_GRID}",
}

# ImageNet statistics the torchvision weights were trained with (RGB order, on [0, 1] pixels).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

PREPROCESSING = (
    f"uint8 RGB -> cv2.resize {IMAGE_SIZE}x{IMAGE_SIZE} INTER_AREA (full frame, no crop) "
    f"-> /255 -> ImageNet mean {IMAGENET_MEAN} std {IMAGENET_STD}"
)

# ImageNet weights: an explicit file (environment variable) or the torch hub cache, in this order.
WEIGHTS_ENV_VAR = "CNEP_MOBILENET_WEIGHTS"
IMAGENET_WEIGHT_FILES = {
    "mobilenet_v2-b0353104.pth": "https://download.pytorch.org/models/mobilenet_v2-b0353104.pth",
    "mobilenet_v2-7ebf99e0.pth": "https://download.pytorch.org/models/mobilenet_v2-7ebf99e0.pth",
}
# When none is there, the first is downloaded into the hub cache (as torchvision does) unless this
# environment variable is set to anything but "", "0", "false" or "no" (or `cnep extract --offline` is given).
OFFLINE_ENV_VAR = "CNEP_OFFLINE"
DOWNLOAD_TIMEOUT_S = 30.0  # seconds without data before a download gives up
CONNECT_TIMEOUT_S = (
    5.0  # seconds for the download's server (or proxy) to accept a connection, all its addresses together
)

# Views of each demonstration's frames `cnep extract` also extracts where it extracts a few demonstrations
# (perception.views; pipeline.extract.stage.views_for), and the most it takes: a file holds its features once per view.
DEFAULT_VIEWS = 7
MAX_VIEWS = 16

# Batch-norm re-estimation for seeded random weights (see docs/concepts.md).
CALIBRATION_FRAMES = 256  # frames used to re-estimate the statistics (spread over the inputs)
CALIBRATION_BATCH = 32  # frames per forward pass while re-estimating

DEFAULT_BATCH_SIZE = 4  # frames per forward pass: small batches stay in cache, the fastest on a CPU
# Frames per forward pass on a GPU: a GPU wants large batches, and most of the gain comes by this one
# (docs/results-scale.md).
CUDA_BATCH_SIZE = 64
# Fastest first: a CUDA device when torch sees one, then as `python -m benchmarks.bench_perception` ranks them on
# a CPU. OpenVINO (the `openvino` extra) ties ONNX Runtime on fp32 (benchmarks/bench_threads.py), so `auto` keeps
# ONNX Runtime.
BACKENDS = ("cuda", "onnxruntime", "openvino", "torchscript", "eager")
# Backends that run the int8 graph, fastest first (docs/results.md).
INT8_BACKENDS = ("openvino", "onnxruntime")
# The Python modules each optional backend needs (the ONNX export, then the runtime).
BACKEND_MODULES = {"onnxruntime": ("onnx", "onnxruntime"), "openvino": ("onnx", "openvino")}

# Identity fields that must agree for features from two files to be mixed (the backend may differ).
COMPATIBILITY_FIELDS = ("architecture", "feature_dim", "weights_sha256", "preprocessing")

ONNX_OPSET = 17  # opset of the exported FeatureNet graph (part of the export cache's key)
CACHE_ENV_VAR = "CNEP_CACHE_DIR"  # where exported ONNX graphs are cached (default: ~/.cache/cnep)
PRECISIONS = ("fp32", "int8")  # feature extraction precision; int8: perception.quantisation (ONNX Runtime)
