import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    """The models here are tiny: one thread is faster and leaves the other core to the rest."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
