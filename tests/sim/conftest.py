import pickle
from concurrent.futures import Executor, Future
from contextlib import contextmanager

import pytest

# Frames that calibrate the random feature weights in the end-to-end runs here: one calibration batch, where the
# command takes perception.constants.CALIBRATION_FRAMES. These tests check the stages and the summary, not how well
# the features tell scenes apart (tests/pipeline/test_scene.py does).
FEW_CALIBRATION_FRAMES = 32


def calibrate_on_few_frames(monkeypatch: pytest.MonkeyPatch) -> None:
    """`cnep extract` calibrates random weights on FEW_CALIBRATION_FRAMES frames while `monkeypatch` holds."""
    import cnep.pipeline.extract.stage as extract_stage

    monkeypatch.setattr(extract_stage, "CALIBRATION_FRAMES", FEW_CALIBRATION_FRAMES)


@pytest.fixture
def few_calibration_frames(monkeypatch):
    """`calibrate_on_few_frames` while the test runs."""
    calibrate_on_few_frames(monkeypatch)


class InProcess(Executor):
    """An executor that runs each job when it is submitted, in this process (concurrent.futures' interface); with
    `pickled`, it pickles the call and its result as a process pool does: what a worker process would be sent and
    would send back."""

    def __init__(self, pickled: bool = False):
        self.pickled = pickled

    def submit(self, fn, /, *args, **kwargs) -> Future:
        future = Future()
        try:
            if self.pickled:
                fn, args, kwargs = pickle.loads(pickle.dumps((fn, args, kwargs)))
            result = fn(*args, **kwargs)
            future.set_result(pickle.loads(pickle.dumps(result)) if self.pickled else result)
        except Exception as error:
            future.set_exception(error)
        return future


@contextmanager
def in_process(workers: int, wait: bool = True):
    """pipeline.workers.single_thread_processes' stand-in: the jobs run in this process, one after the other."""
    yield InProcess()


@contextmanager
def pickled_in_process(workers: int, *args, **kwargs):
    """pipeline.workers.process_pool's stand-in: the jobs run in this process, one after the other, each call and its
    result pickled as the pool's processes would receive and return them."""
    yield InProcess(pickled=True)


@pytest.fixture
def sim_pools_in_process(monkeypatch, one_thread):
    """`pools_in_process` while the test runs, on one torch thread as in a worker."""
    pools_in_process(monkeypatch)


def pools_in_process(monkeypatch: pytest.MonkeyPatch) -> None:
    """The sim stage's worker pools (training, the closed loop, the CNEP-PCA baseline's training) run their jobs in
    this process while `monkeypatch` holds: no process to start, no torch to import again. The pools themselves are
    pipeline.workers' (tests/pipeline/test_workers.py), and the quick demo trains the same `train` jobs in them. (The
    CNEP-PCA trains in a process of its own because torch's optimiser may crash a process that holds a MuJoCo
    renderer: a test's process has trained before its closed loop starts, the optimiser already loaded.)"""
    import cnep.pipeline.demo.stage as demo_stage
    import cnep.pipeline.evaluate.pool as pool
    import cnep.pipeline.sim.baselines as sim_baselines

    # the closed loop's and the selection's (pipeline.evaluate.pool), the training's (demo.stage.train_side_by_side)
    for module in (pool, demo_stage):
        monkeypatch.setattr(module, "single_thread_processes", in_process)
    monkeypatch.setattr(sim_baselines, "process_pool", pickled_in_process)  # the CNEP-PCA's training (pca_cnep)
