import pytest


@pytest.fixture(autouse=True)
def no_downloads(monkeypatch):
    """Tests never reach the internet: ImageNet weights are not downloaded unless a test allows it."""
    monkeypatch.setenv("CNEP_OFFLINE", "1")


@pytest.fixture
def one_thread():
    """Tiny models train faster on one torch thread, and it leaves the other core to the rest."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
