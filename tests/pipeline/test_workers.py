import os

import pytest

from cnep.pipeline.workers import SMALL_MODEL_MALLOC, THREAD_VARIABLES, single_thread_processes


def threads_seen() -> tuple[dict, int]:
    import torch

    return {name: os.environ.get(name) for name in (*THREAD_VARIABLES, *SMALL_MODEL_MALLOC)}, torch.get_num_threads()


@pytest.mark.slow
def test_workers_start_with_one_thread_and_the_environment_is_restored(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    for name in SMALL_MODEL_MALLOC:
        monkeypatch.delenv(name, raising=False)
    with single_thread_processes(1) as pool:
        env, torch_threads = pool.submit(threads_seen).result()
    assert env == {**dict.fromkeys(THREAD_VARIABLES, "1"), **SMALL_MODEL_MALLOC}
    assert torch_threads == 1
    assert os.environ["OMP_NUM_THREADS"] == "7"
    assert not {"MKL_NUM_THREADS", *SMALL_MODEL_MALLOC} & set(os.environ)


def test_inference_threads_share_the_cores_unless_given(monkeypatch):
    from cnep.pipeline import workers

    monkeypatch.setattr(workers, "cpu_cores", lambda: 8)
    assert workers.inference_threads() == 8
    assert workers.inference_threads(workers=3) == 2
    assert workers.inference_threads(workers=16) == 1
    assert workers.inference_threads(5, workers=4) == 5  # --threads wins


def test_torch_threads_is_restored():
    import torch

    from cnep.models.threads import torch_threads

    before = torch.get_num_threads()
    with torch_threads(3):
        assert torch.get_num_threads() == 3
    assert torch.get_num_threads() == before
