import pytest


@pytest.fixture(autouse=True)
def _one_thread_for_every_model_test(one_thread):
    yield
