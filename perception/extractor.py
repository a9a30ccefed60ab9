"""The feature extractor: uint8 RGB frames of any size (N, H, W, 3) -> float32 features (N, 1280)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from cnep.perception.backends import (
    INSTALL_HINT,
    Runner,
    available_backends,
    build_runner,
    onnx_model,
    onnxruntime_runner,
    openvino_runner,
)
from cnep.perception.calibration import ACTIVATION_BIAS, calibrate_random_network
from cnep.perception.constants import (
    ARCHITECTURES,
    CALIBRATION_BATCH,
    CUDA_BATCH_SIZE,
    DEFAULT_BATCH_SIZE,
    FEATURE_DIM,
    INT8_BACKENDS,
    PRECISIONS,
    PREPROCESSING,
)
from cnep.perception.errors import PerceptionError
from cnep.perception.frames import resize_frames
from cnep.perception.network import FeatureNet, mobilenet_v2_features
from cnep.perception.quantisation import QUANTISATION, pixels_sha256, quantise_int8
from cnep.perception.weights import resolve_weights, save_state_dict, state_dict_sha256

log = logging.getLogger(__name__)


class FeatureExtractor:
    """MobileNet-v2 features + pooling (`global`, or `cells` for seeded random weights: perception.network),
    batched, eval + inference mode.

    weights: `imagenet`, a state-dict path, or `random` (seeded by `seed`; call `calibrate` on frames of
    the recordings before extracting, see perception.calibration). backend: `auto` (fastest available
    for the precision), `cuda`, `onnxruntime`, `openvino`, `torchscript` or `eager`. threads: CPU threads
    for inference (None: library default). batch_size: frames per forward pass (None: CUDA_BATCH_SIZE on a
    GPU, else DEFAULT_BATCH_SIZE). precision: `fp32` (default) or `int8` (quantised by ONNX Runtime, run
    by OpenVINO or ONNX Runtime on the CPU; call `quantise` on frames of the recordings before extracting,
    see perception.quantisation).
    """

    def __init__(
        self,
        weights: str | Path = "imagenet",
        backend: str = "auto",
        threads: int | None = None,
        batch_size: int | None = None,
        seed: int = 0,
        precision: str = "fp32",
    ) -> None:
        if precision not in PRECISIONS:
            raise PerceptionError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        if precision == "int8" and (
            backend not in ("auto", *INT8_BACKENDS) or "onnxruntime" not in available_backends()
        ):
            raise PerceptionError(
                f"precision int8 is quantised by ONNX Runtime and runs on backend `auto`, "
                f"{' or '.join(f'`{b}`' for b in INT8_BACKENDS)} (pip install "
                f"'cnep-pipeline[onnx]'), got backend {backend!r}"
            )
        if batch_size is not None and batch_size < 1:
            raise PerceptionError(f"batch_size must be >= 1, got {batch_size}")
        if threads is not None and threads < 1:
            raise PerceptionError(f"threads must be >= 1 (or None for the default), got {threads}")
        if backend != "auto" and backend not in available_backends():
            raise PerceptionError(
                f"backend {backend!r} is not available; choose `auto` or one of {available_backends()} ({INSTALL_HINT})"
            )
        resolved = resolve_weights(weights, seed)
        features = mobilenet_v2_features()
        features.load_state_dict(resolved.state_dict)
        self.net = FeatureNet(features, resolved.pooling).eval()
        self.weights_name = resolved.name
        self.calibrated_on = 0  # frames used to re-estimate batch-norm statistics (0: as loaded)
        self.backend, self.threads, self.precision = backend, threads, precision
        self.batch_size = batch_size or (CUDA_BATCH_SIZE if self._resolved_backend() == "cuda" else DEFAULT_BATCH_SIZE)
        self._runner: Runner | None = None
        self._sha256 = state_dict_sha256(self.net.features.state_dict())  # the pooling is in the architecture
        self._needs_calibration = resolved.is_random
        self._int8_model: bytes | None = None  # the quantised graph, once `quantise` ran
        self._quantised_on = ""  # "frames=N,sha256=..." of the quantisation's calibration pixels

    @property
    def needs_calibration(self) -> bool:
        """True for random weights whose batch-norm statistics were not re-estimated yet."""
        return self._needs_calibration

    def calibrate(self, frames: np.ndarray, done: Callable[[int], object] | None = None) -> None:
        """Calibrate random weights on (N, H, W, 3) uint8 frames, N >= 2 (perception.calibration); changes the hash.

        done: called with the number of frames of each batch once it has gone through the network (a bar's update).
        """
        if not self.weights_name.startswith("random:"):
            raise PerceptionError(f"calibrate() is for seeded random weights; {self.weights_name} are used as given")
        pixels = resize_frames(frames)  # (N, 224, 224, 3)

        def batches() -> Iterator[np.ndarray]:
            for i in range(0, len(pixels), CALIBRATION_BATCH):
                yield pixels[i : i + CALIBRATION_BATCH]  # (B, 224, 224, 3)
                if done is not None:  # the network asked for the next batch: this one went through
                    done(len(pixels[i : i + CALIBRATION_BATCH]))

        self.calibrated_on = calibrate_random_network(self.net, batches())
        self._sha256 = state_dict_sha256(self.net.features.state_dict())
        self._needs_calibration = False
        self._int8_model = None  # quantised from the old weights: quantise again
        self._runner = None  # compiled backends hold a frozen copy of the old statistics
        log.info("calibrated random weights on %d frames (weights sha256 %s)", self.calibrated_on, self._sha256[:12])

    @property
    def needs_quantisation(self) -> bool:
        """True for precision int8 before `quantise` (or after `calibrate` changed the weights)."""
        return self.precision == "int8" and self._int8_model is None

    def quantise(self, frames: np.ndarray) -> None:
        """int8 only: quantise the network, activation ranges calibrated on (N, H, W, 3) uint8 frames of the
        recordings."""
        if self.precision != "int8":
            raise PerceptionError("quantise() is for precision int8; this extractor runs fp32")
        if self._needs_calibration:
            raise PerceptionError(f"weights {self.weights_name} need calibrate(frames) before they are quantised")
        pixels = resize_frames(frames)  # (N, 224, 224, 3)
        batches = [pixels[i : i + CALIBRATION_BATCH] for i in range(0, len(pixels), CALIBRATION_BATCH)]
        calibration = pixels_sha256(batches)
        self._int8_model = quantise_int8(
            onnx_model(self.net, self._graph_key), batches, cache_key=f"{self._graph_key}|{calibration}"
        )
        self._quantised_on = f"frames={len(pixels)},sha256={calibration[:16]}"
        self._runner = None
        log.info("quantised to int8 on %d frames (%s)", len(pixels), self._quantised_on)

    @property
    def identity(self) -> dict[str, str]:
        """What produced the features, as flat strings for file metadata (see `compatibility_key`)."""
        weights = self.weights_name
        if self.calibrated_on:
            weights += f"+calibrated:bias={ACTIVATION_BIAS},frames={self.calibrated_on}"
        return {
            "architecture": ARCHITECTURES[self.net.pooling],
            "feature_dim": str(FEATURE_DIM),
            "weights": weights,
            "weights_sha256": self._sha256,
            "preprocessing": PREPROCESSING,
            "backend": self._resolved_backend(),
            **(
                {"precision": "int8", "quantisation": f"{QUANTISATION},{self._quantised_on}"}
                if self.precision == "int8"
                else {}
            ),
        }

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """Features of (N, H, W, 3) uint8 RGB frames of any size: (N, 1280) float32, in batches of batch_size."""
        return self.features(resize_frames(frames))

    def features(self, pixels: np.ndarray) -> np.ndarray:
        """Features of frames already resized to (N, 224, 224, 3) uint8: (N, 1280) float32."""
        if self._needs_calibration:
            raise PerceptionError(
                f"weights {self.weights_name} are freshly initialised: their features are below 1e-5 "
                f"and carry no signal; call calibrate(frames) with frames of the recordings first"
            )
        if self.needs_quantisation:
            raise PerceptionError("precision int8 needs quantise(frames) with frames of the recordings first")
        runner = self._get_runner()
        out = np.empty((len(pixels), FEATURE_DIM), dtype=np.float32)  # (N, 1280)
        for i in range(0, len(pixels), self.batch_size):
            out[i : i + self.batch_size] = runner(np.ascontiguousarray(pixels[i : i + self.batch_size]))
        return out

    def prepare(self) -> None:
        """Build the backend now rather than at the first batch (ONNX export and tracing take seconds)."""
        if self._needs_calibration:
            raise PerceptionError(f"weights {self.weights_name} need calibrate(frames) before the backend is built")
        if self.needs_quantisation:
            raise PerceptionError("precision int8 needs quantise(frames) before the backend is built")
        self._get_runner()

    def onnx_graph(self) -> bytes:
        """The ONNX graph ONNX Runtime and OpenVINO run for these features (uint8 pixels (N, 224, 224, 3) ->
        (N, 1280)): the fp32 export, or for precision int8 its quantisation (after `quantise`)."""
        if self._needs_calibration:
            raise PerceptionError(f"weights {self.weights_name} need calibrate(frames) before they are exported")
        if self.needs_quantisation:
            raise PerceptionError("precision int8 needs quantise(frames) before it is exported")
        return self._int8_model if self._int8_model is not None else onnx_model(self.net, self._graph_key)

    def save_weights(self, path: Path) -> None:
        """Save the (possibly calibrated) weights, to reuse them later as weights=`path`."""
        save_state_dict(self.net.features.state_dict(), path, self.net.pooling)

    def __getstate__(self) -> dict:
        """Pickled without its backend (a compiled session does not pickle): the receiver builds its own."""
        return {**self.__dict__, "_runner": None}

    def _get_runner(self) -> Runner:
        if self._runner is None and self._int8_model is not None:
            run_on = openvino_runner if self._resolved_backend() == "openvino" else onnxruntime_runner
            self._runner = run_on(self._int8_model, self.threads)
        elif self._runner is None:
            self._runner = build_runner(self._resolved_backend(), self.net, self.threads, cache_key=self._graph_key)
        return self._runner

    @property
    def _graph_key(self) -> str:
        """What the exported graph depends on: the weights and the pooling (cache key of the ONNX exports)."""
        return f"{self._sha256}|{self.net.pooling}"

    def _resolved_backend(self) -> str:
        if self.backend != "auto":
            return self.backend
        if self.precision == "int8":
            return next(backend for backend in INT8_BACKENDS if backend in available_backends())
        return available_backends()[0]
