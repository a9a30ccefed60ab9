import numpy as np
import pytest

from perception import FeatureExtractor, available_backends

from .conftest import scene_frames


def test_eager_is_always_available_and_auto_picks_the_first():
    backends = available_backends()
    assert "eager" in backends and "torchscript" in backends
    assert FeatureExtractor("random", threads=1).identity["backend"] == backends[0]


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
    from perception import backends

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
    from perception.backends import session_options

    options = session_options(1)
    assert options.get_session_config_entry("session.intra_op.allow_spinning") == "0"
    assert options.intra_op_num_threads == 1
