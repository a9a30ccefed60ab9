import fcntl
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

# One BLAS / OpenMP thread per test process, set before numpy and torch load their libraries: on a shared
# 2-core machine a second thread per library made a GMM test 90x slower under load (601 s instead of 6.8 s).
# A value set by the caller is kept.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")
os.environ.setdefault(
    "CNEP_CACHE_DIR", os.path.join(os.environ.get("TMPDIR", "/tmp"), f"cnep-test-cache-{os.getuid()}")
)
# matplotlib's font cache in one folder for every test and the processes they start: it lives under HOME otherwise,
# and the tests that give a command a fresh HOME (the rerun CLI writes there) would each have it rebuilt.
os.environ.setdefault(
    "MPLCONFIGDIR", os.path.join(os.environ.get("TMPDIR", "/tmp"), f"cnep-test-matplotlib-{os.getuid()}")
)

import pytest  # noqa: E402

from cnep.pipeline.workers import SMALL_MODEL_MALLOC  # noqa: E402

# glibc's malloc settings of the pipeline's small-model workers for every test process too: the feature network's
# batches and the trainers' steps would otherwise give their buffers back to the kernel and fault them in again on
# the next pass. glibc reads them when a process starts, so they reach the worker processes (pytest-xdist starts
# them after this file is read) and every command a test starts; a value set by the caller is kept.
for _name, _value in SMALL_MODEL_MALLOC.items():
    os.environ.setdefault(_name, _value)

# Session fixtures that run the whole pipeline (the quick demo and what is built on it): a test that uses one is
# slow (`make test-fast` leaves it out), whatever its own body costs.
PIPELINE_FIXTURES = {"quick_demo", "policy_world", "demo_run"}


@pytest.hookimpl(tryfirst=True)  # marks the groups before pytest-xdist reads them
def pytest_collection_modifyitems(items):
    """Marks and an order for `make test`'s worker processes (pytest-xdist `--dist loadgroup` hands the tests out in
    this order, one at a time unless grouped): a test of the pipeline's fixtures is slow; the tests that share a
    module fixture go to one worker together (each worker would build it); slow tests first, so that the last ones
    handed out are short and the workers finish together, and one that builds the quick demo before them all, so
    that meanwhile the other worker runs tests that do not need it instead of waiting for it."""
    for item in items:
        if uses(item, PIPELINE_FIXTURES):
            item.add_marker(pytest.mark.slow)
        if uses_module_fixture(item):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0]))
    first_demo = next((item for item in items if uses(item, PIPELINE_FIXTURES)), None)

    def rank(item) -> int:
        if item is first_demo:
            return 0
        if item.get_closest_marker("slow") is None:
            return 3
        return 2 if uses(item, PIPELINE_FIXTURES) else 1

    items.sort(key=rank)


def uses(item, fixtures: set[str]) -> bool:
    return bool(fixtures & set(getattr(item, "fixturenames", ())))


def uses_module_fixture(item) -> bool:
    info = getattr(item, "_fixtureinfo", None)  # pytest's record of the fixtures a test resolves
    return info is not None and any(d.scope == "module" for defs in info.name2fixturedefs.values() for d in defs)


def built_once(tmp_path_factory, name: str, build) -> Path:
    """The folder `name` that `build(folder)` fills, built once per test run: the first worker process (pytest-xdist)
    to ask builds it while the others wait for it, then all read it (a session fixture alone is built once per
    worker). A build that failed is tried again by the next worker to ask."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # the parent: one per run, shared
    folder, done = root / name, root / f"{name}.done"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            build(folder)
            done.touch()
    return folder


@pytest.fixture(autouse=True)
def no_downloads(monkeypatch):
    """Tests never reach the internet: ImageNet weights are not downloaded unless a test allows it."""
    monkeypatch.setenv("CNEP_OFFLINE", "1")


@pytest.fixture
def hub(tmp_path, monkeypatch):
    """An empty torch hub cache, downloads allowed, no environment override: its checkpoints folder (not created)."""
    from cnep.perception.constants import OFFLINE_ENV_VAR, WEIGHTS_ENV_VAR

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.delenv(WEIGHTS_ENV_VAR, raising=False)
    monkeypatch.delenv(OFFLINE_ENV_VAR, raising=False)
    return tmp_path / "torch" / "hub" / "checkpoints"


@pytest.fixture
def served(tmp_path):
    """(server, file name): a seeded MobileNet-v2 state dict served on 127.0.0.1 under a torchvision-style name."""
    from tests.weights_server import WeightsServer, torchvision_named_weights

    name = torchvision_named_weights(tmp_path / "www")
    server = WeightsServer(tmp_path / "www")
    yield server, name
    server.close()


@pytest.fixture
def one_thread():
    """Tiny models train faster on one torch thread, and it leaves the other core to the rest."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def ctrl_c_raises():
    """SIGINT raises KeyboardInterrupt during the test, as in a terminal, even where the tests were started with it
    ignored (a script's background job inherits SIGINT ignored, and Python keeps it so)."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


@pytest.fixture(scope="session")
def quick_demo(tmp_path_factory):
    """`cnep demo --quick` once per test session, run as a user runs it (a process of its own: loading torch is part
    of what it shows), its outputs in `<tmp>/cnep-demo` as `make demo` leaves them (the rerun CLI it calls writes
    analytics under HOME unless CI is set: a temporary HOME, CI=1). Offline with an empty torch hub cache, as a
    machine without internet access runs it: the features come from seeded random weights. Its stderr, each line with
    the seconds since the command started, is kept in PROGRESS_LOG beside OUT."""
    return built_once(tmp_path_factory, "demo", lambda folder: run_quick_demo(folder, tmp_path_factory)) / "cnep-demo"


def run_quick_demo(folder: Path, tmp_path_factory) -> None:
    """`cnep demo --quick --out folder/cnep-demo` in a process of its own, its timed stderr in folder/PROGRESS_LOG."""
    from cnep.perception.constants import OFFLINE_ENV_VAR, WEIGHTS_ENV_VAR

    env = {**os.environ, "HOME": str(tmp_path_factory.mktemp("home")), "CI": "1", OFFLINE_ENV_VAR: "1"}
    env["TORCH_HOME"] = str(tmp_path_factory.mktemp("torch"))
    env.pop(WEIGHTS_ENV_VAR, None)
    out = folder / "cnep-demo"
    command = [sys.executable, "-m", "cnep.pipeline", "demo", "--out", str(out), "--quick"]
    start = time.monotonic()
    demo = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    timed: list[str] = []  # "<seconds> <line>", each line with the time it arrived
    reader = threading.Thread(
        target=lambda: timed.extend(f"{time.monotonic() - start:.2f} {line}" for line in demo.stderr)
    )
    reader.start()
    demo.stdout.read()
    reader.join()
    assert demo.wait() == 0, "".join(timed[-30:])
    (folder / PROGRESS_LOG).write_text("".join(timed))


PROGRESS_LOG = "progress.log"  # beside the quick demo's folder: "<seconds since start> <line>" per stderr line


@pytest.fixture(scope="session")
def policy_world(quick_demo, tmp_path_factory):
    """The quick demo's policy exported, a motion policy and their recordings (tests/policy_world.py), built once
    per test run."""
    import torch

    from tests.policy_world import PolicyWorld, build_policy_world

    def build(folder: Path) -> None:
        before = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            build_policy_world(quick_demo, folder)
        finally:
            torch.set_num_threads(before)

    return PolicyWorld.of(quick_demo, built_once(tmp_path_factory, "policy", build))


# The motion world's training: tiny networks, seeded, with resumable saves (tests/pipeline/test_faults.py re-runs it
# interrupted and compares).
MOTION_TRAINING = ["--layout", "motion", "--steps", "40", "--val-every", "10", "--save-every", "10"]
MOTION_TRAINING += ["--warmup-steps", "4", "--encoder-widths", "8", "--expert-widths", "8", "--batch-size", "4"]
MOTION_TRAINING += ["--seed", "1"]


@pytest.fixture(scope="session")
def motion_world(tmp_path_factory):
    """Motion-only inputs and the outputs of uninterrupted `cnep` runs, built once per test run and never written to
    by the tests: `src` (4 CSVs of 40 rows with the usual column names), `demos` (ingested), `trajs` (extracted),
    `ckpt` (trained with MOTION_TRAINING), `other_ckpt` (the same with 3 experts: another model for the same
    recordings)."""
    from types import SimpleNamespace

    root = built_once(tmp_path_factory, "motion-world", build_motion_world)
    names = ("src", "demos", "trajs", "ckpt", "other")
    return SimpleNamespace(**{name: root / name for name in names}, other_ckpt=root / "other")


def build_motion_world(root: Path) -> None:
    import numpy as np
    import torch

    from cnep.pipeline.cli.main import main

    (root / "src").mkdir()
    t = np.arange(40) * 0.05
    for k in range(4):
        rows = [[ti, 0.3 + 0.1 * k + 0.2 * ti, 0.1 * np.sin(ti + k), 0.2, 0, 0, 0, 1, 0.01 * k] for ti in t]
        text = "\n".join(["t,x,y,z,qx,qy,qz,qw,gripper", *(",".join(map(repr, map(float, r))) for r in rows)])
        (root / "src" / f"demo_{k}.csv").write_text(text + "\n")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        assert main(["-q", "ingest", str(root / "src"), "--out", str(root / "demos")]) == 0
        assert main(["-q", "extract", str(root / "demos"), "--out", str(root / "trajs")]) == 0
        assert main(["-q", "train", str(root / "trajs"), "--out", str(root / "ckpt"), *MOTION_TRAINING]) == 0
        other = [*MOTION_TRAINING, "--experts", "3"]
        assert main(["-q", "train", str(root / "trajs"), "--out", str(root / "other"), *other]) == 0
    finally:
        torch.set_num_threads(threads)
