"""int8 feature extraction: static per-channel QDQ quantisation of the FeatureNet graph (ONNX Runtime).

Weights are quantised per output channel (int8, symmetric); activations per tensor (uint8), their
ranges calibrated (min-max) on frames of the recordings. uint8 activations ("U8S8"): with int8 ones
(S8S8) the graph ran slower than fp32 on an AMD CPU, with uint8 faster, at the same feature error. The
result is an ONNX graph with QuantizeLinear/DequantizeLinear pairs around each convolution, which
ONNX Runtime, or OpenVINO reading the same graph (perception.backends.openvino_runner), fuses into
int8 kernels. Its identity (precision, the calibration frames' sha256) goes into the extractor's
identity, so int8 features are never mixed with fp32 ones (perception.compatibility_key).
Feature error and speed against fp32: benchmarks/bench_threads.py, docs/results.md.
"""

from __future__ import annotations

import hashlib
import logging
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cnep.perception.backends import cache_path, write_cache_file

QUANTISATION = "onnxruntime static QDQ, weights int8 per channel, activations uint8 per tensor, min-max"


def pixels_sha256(batches: Sequence[np.ndarray]) -> str:
    """sha256 of the calibration pixels (uint8 (B, 224, 224, 3) batches, in order)."""
    digest = hashlib.sha256()
    for batch in batches:
        digest.update(np.ascontiguousarray(batch).tobytes())
    return digest.hexdigest()


def quantise_int8(model: bytes, batches: Sequence[np.ndarray], cache_key: str | None = None) -> bytes:
    """The int8 QDQ graph of fp32 ONNX `model` (input `pixels`), activation ranges from uint8 (B, 224, 224, 3)
    `batches`.

    With `cache_key` (what identifies `model` and `batches`) the result is cached on disk beside the fp32
    exports (perception.backends.onnx_cache_dir): quantising takes seconds to tens of seconds.
    """
    import onnxruntime as ort
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    identity = f"{cache_key}|{QUANTISATION}|onnxruntime={ort.__version__}"
    path = None if cache_key is None else cache_path("featurenet-int8", identity)
    if path is not None and path.is_file():
        return path.read_bytes()

    class Frames(CalibrationDataReader):
        def __init__(self) -> None:
            self.pending = iter(batches)

        def get_next(self) -> dict | None:
            batch = next(self.pending, None)
            return None if batch is None else {"pixels": np.ascontiguousarray(batch)}

    ort.set_default_logger_severity(3)  # the quantiser's graph clean-up warns about every folded constant
    hint = _DropLogRecords("before quantization")  # its advice to pre-process (measured: no faster here)
    logging.getLogger().addFilter(hint)
    try:
        with tempfile.TemporaryDirectory(prefix="cnep-int8-") as tmp:
            src, dst = Path(tmp) / "fp32.onnx", Path(tmp) / "int8.onnx"
            src.write_bytes(model)
            quantize_static(
                src,
                dst,
                Frames(),
                quant_format=QuantFormat.QDQ,
                per_channel=True,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
            )
            quantised = dst.read_bytes()
    finally:
        ort.set_default_logger_severity(2)  # ONNX Runtime's default: warnings
        logging.getLogger().removeFilter(hint)
    if path is not None:
        write_cache_file(path, quantised)
    return quantised


class _DropLogRecords(logging.Filter):
    """Drops log records whose message contains `text`."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text

    def filter(self, record: logging.LogRecord) -> bool:
        return self.text not in record.getMessage()
