import numpy as np
import pytest

from cnep.perception import FeatureExtractor, available_backends

from .conftest import scene_frames


def test_eager_is_always_available_and_auto_picks_the_first():
    backends = available_backends()
    assert "eager" in backends and "torchscript" in backends
    assert FeatureExtractor("random", threads=1).identity["backend"] == backends[0]


@pytest.mark.slow
def test_all_backends_agree_on_the_same_frames():
    frames = np.concatenate([scene_frames(k, n=3, seed=k) for k in range(2)])  # (6, 60, 80, 3)
    features = {}
    for backend in available_backends():
        extractor = FeatureExtractor("random", backend=backend, threads=1, batch_size=4)
        extractor.calibrate(frames)
        features[backend] = extractor(frames)
        assert features[backend].shape == (6, 1280) and features[backend].dtype == np.float32
    reference = features.pop("eager")
    for backend, values in features.items():
        cosine = (values * reference).sum(1) / np.linalg.norm(values, axis=1) / np.linalg.norm(reference, axis=1)
        assert cosine.min() >= 0.9999, (backend, cosine.min())


@pytest.mark.skipif("onnxruntime" not in available_backends(), reason="needs the onnx extra")
def test_onnxruntime_is_the_default_on_a_cpu_when_installed():
    assert [b for b in available_backends() if b != "cuda"][0] == "onnxruntime"


def test_cuda_is_offered_first_exactly_when_torch_sees_a_gpu(monkeypatch):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert "cuda" not in available_backends()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert available_backends()[0] == "cuda"


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="needs a CUDA GPU")
def test_cuda_is_the_default_on_a_gpu_with_gpu_sized_batches():
    extractor = FeatureExtractor("random")
    assert extractor.identity["backend"] == "cuda" and extractor.batch_size == 64
    assert FeatureExtractor("random", backend="eager").batch_size == 4


@pytest.mark.skipif("onnxruntime" not in available_backends(), reason="needs the onnx extra")
def test_onnx_export_is_cached_by_weights_hash(monkeypatch, tmp_path):
    from cnep.perception import backends

    monkeypatch.setenv("CNEP_CACHE_DIR", str(tmp_path))
    net = FeatureExtractor("random", threads=1).net
    first = backends.onnx_model(net, cache_key="abc")
    cached = list((tmp_path / "onnx").iterdir())
    assert len(cached) == 1 and cached[0].read_bytes() == first
    monkeypatch.setattr(backends.torch.onnx, "export", lambda *a, **k: pytest.fail("exported again"))
    assert backends.onnx_model(net, cache_key="abc") == first  # read from the cache
    with pytest.raises(pytest.fail.Exception):
        backends.onnx_model(net, cache_key="other weights")


@pytest.mark.skipif("onnxruntime" not in available_backends(), reason="needs the onnx extra")
def test_onnxruntime_sessions_do_not_spin():
    from cnep.runtime.sessions import session_options

    options = session_options(1)
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "0"
    assert options.intra_op_num_threads == 1


def _relative_l2(values: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return np.linalg.norm(values - reference, axis=1) / np.linalg.norm(reference, axis=1)  # (N,)


needs_openvino = pytest.mark.skipif(
    not {"onnxruntime", "openvino"} <= set(available_backends()), reason="needs the onnx and openvino extras"
)


@pytest.mark.slow
@needs_openvino
@pytest.mark.parametrize("precision", ["fp32", "int8"])
def test_openvino_features_equal_onnxruntime_ones(precision):
    # Seeded random weights (calibrated on two synthetic scenes), the same ONNX graph on both runtimes.
    # fp32: the same numbers. int8: each runtime rounds with its own int8 kernels, whose results depend on the
    # processor's instructions (AVX2 alone or VNNI), so the two agree only as closely as each agrees with fp32.
    # Random weights pool by cells, one map location per channel, so int8's rounding is not averaged away
    # (measured: docs/results.md, the extract stage's speed).
    frames = np.concatenate([scene_frames(k, n=3, seed=k) for k in range(2)])  # (6, 60, 80, 3)
    reference = FeatureExtractor("random", backend="onnxruntime", threads=1)
    reference.calibrate(frames)
    fp32 = reference(frames)  # (6, 1280)
    features = {}
    for backend in ("onnxruntime", "openvino"):
        extractor = FeatureExtractor("random", backend=backend, threads=1, precision=precision)
        extractor.calibrate(frames)
        if precision == "int8":
            extractor.quantise(frames)
        features[backend] = extractor(frames)  # (6, 1280)
        assert extractor.identity["backend"] == backend
    error = _relative_l2(features["openvino"], features["onnxruntime"])
    if precision == "fp32":
        assert error.max() <= 1e-5, error
    else:
        own = max(_relative_l2(features[b], fp32).max() for b in features)  # each runtime's int8 error
        assert own <= 0.2 and error.max() <= 1.5 * own, (error, own)


@pytest.mark.slow
@needs_openvino
def test_auto_runs_int8_on_openvino_and_fp32_on_onnxruntime():
    frames = scene_frames(0, n=4)
    fp32 = FeatureExtractor("random", threads=1)
    int8 = FeatureExtractor("random", threads=1, precision="int8")
    for extractor in (fp32, int8):
        extractor.calibrate(frames)
    int8.quantise(frames)
    cpu_default = "cuda" if __import__("torch").cuda.is_available() else "onnxruntime"
    assert (fp32.identity["backend"], int8.identity["backend"]) == (cpu_default, "openvino")
    error = _relative_l2(int8(frames), fp32(frames))
    assert 1e-3 < error.max() < 0.2  # int8 kernels ran (not the fp32 graph), at int8's error (1.2e-1 measured)


@needs_openvino
def test_openvino_runs_the_requested_threads_unpinned():
    import openvino as ov

    from cnep.perception.backends import onnx_model
    from cnep.runtime.sessions import openvino_config

    extractor = FeatureExtractor("random", threads=1)
    core = ov.Core()
    graph = core.read_model(onnx_model(extractor.net, cache_key=extractor.identity["weights_sha256"]))
    compiled = core.compile_model(graph, "CPU", openvino_config(1))
    assert compiled.get_property("INFERENCE_NUM_THREADS") == 1
    assert compiled.get_property("NUM_STREAMS") == 1
    assert compiled.get_property("ENABLE_CPU_PINNING") is False


@pytest.mark.slow
def test_a_torch_runner_leaves_the_process_thread_count_as_it_was():
    """torch's thread count is process-wide: the extractor uses its threads during a call, not after it."""
    import torch

    from cnep.perception.backends import build_runner

    before = torch.get_num_threads()
    seen = []
    net = FeatureExtractor("random", backend="eager", threads=1).net

    class Spy(torch.nn.Module):
        def forward(self, pixels):
            seen.append(torch.get_num_threads())
            return net(pixels)

    run = build_runner("eager", Spy(), threads=before + 1)
    assert torch.get_num_threads() == before
    run(np.zeros((1, 224, 224, 3), dtype=np.uint8))
    assert seen == [before + 1] and torch.get_num_threads() == before
