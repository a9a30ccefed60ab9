import os

# One BLAS / OpenMP thread per test process, set before numpy and torch load their libraries: on a shared
# 2-core machine a second thread per library made a GMM test 90x slower under load (601 s instead of 6.8 s).
# A value set by the caller is kept.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
os.environ.setdefault(
    "CNEP_CACHE_DIR", os.path.join(os.environ.get("TMPDIR", "/tmp"), f"cnep-test-cache-{os.getuid()}")
)

import pytest  # noqa: E402


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


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory):
    """`cnep demo --quick` once per test session, its outputs in `<tmp>/cnep-demo` as `make demo` leaves them
    (the rerun CLI it calls writes analytics under HOME unless CI is set: a temporary HOME, CI=1)."""
    import torch

    from cnep.pipeline.cli.main import main

    mp = pytest.MonkeyPatch()
    mp.setenv("HOME", str(tmp_path_factory.mktemp("home")))
    mp.setenv("CI", "1")
    out = tmp_path_factory.mktemp("demo") / "cnep-demo"
    threads = torch.get_num_threads()
    try:
        code = main(["-q", "demo", "--out", str(out), "--quick"])
    finally:
        torch.set_num_threads(threads)
        mp.undo()
    assert code == 0
    return out


@pytest.fixture(scope="session")
def policy_world(quick_demo, tmp_path_factory):
    """The quick demo's policy exported, a motion policy and their recordings (tests/policy_world.py), built once
    per session."""
    import torch

    from tests.policy_world import build_policy_world

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return build_policy_world(quick_demo, tmp_path_factory.mktemp("policy"))
    finally:
        torch.set_num_threads(before)
