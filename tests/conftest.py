import pytest


@pytest.fixture
def one_thread():
    """Tiny models train faster on one torch thread, and it leaves the other core to the rest."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
