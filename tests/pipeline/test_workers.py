import errno
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cnep.pipeline import workers
from cnep.pipeline.workers import SMALL_MODEL_MALLOC, THREAD_VARIABLES, report_manager, single_thread_processes


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


ROOT = Path(__file__).resolve().parents[2]


def bar_then_wait(ready: str) -> None:
    """A worker's job that opens a progress bar (tqdm makes a lock that processes share), says so in the file `ready`
    and waits to be stopped."""
    from tqdm import tqdm

    tqdm(total=1, disable=True).close()
    Path(ready).touch()
    time.sleep(120)


def disk_full() -> None:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "out/state.pt")


FAILING_POOL = """
import sys, time
from pathlib import Path
from cnep.pipeline.contract import run_command
from cnep.pipeline.workers import single_thread_processes
from tests.pipeline.test_workers import bar_then_wait, disk_full

def run():
    with single_thread_processes(2) as pool:
        pool.submit(bar_then_wait, sys.argv[1])
        while not Path(sys.argv[1]).exists():
            time.sleep(0.05)
        pool.submit(disk_full).result()

sys.exit(run_command("sim", run))
"""


def test_the_error_line_of_a_failed_pool_is_the_last_line(tmp_path):
    """A job fails while another worker holds a lock it made: the workers are stopped, and nothing (such as the
    multiprocessing resource tracker's warning about the lock) is printed after the error line."""
    argv = [sys.executable, "-c", FAILING_POOL, str(tmp_path / "ready")]
    done = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 2 and done.stderr.strip().splitlines() == [
        "cnep sim: error: out/state.pt: No space left on device; free some disk space, or choose a path on another disk"
    ], done.stderr


def pid_then_wait(ready: str) -> None:
    """A worker's job that writes its process id to the file `ready` (whole: written, then renamed) and waits."""
    Path(ready + ".part").write_text(str(os.getpid()))
    os.rename(ready + ".part", ready)
    time.sleep(120)


ORPHANED = """
import sys, time
from pathlib import Path
from cnep.pipeline.workers import report_manager, single_thread_processes
from tests.pipeline.test_workers import pid_then_wait

with report_manager() as manager, single_thread_processes(1) as pool:
    Path(sys.argv[1]).write_text(str(manager._process.pid))
    pool.submit(pid_then_wait, sys.argv[2])
    time.sleep(120)
"""


def running(pid: int) -> bool:
    """Whether process `pid` exists and has not ended (a zombie waiting for its new parent to reap it has)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except FileNotFoundError:
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
def test_workers_end_when_the_process_that_started_them_is_killed(tmp_path):
    """Killed outright (SIGKILL: nothing of it runs), a command stops no one: its pool's worker and its report
    manager's server end by themselves within seconds instead of going on with their jobs."""
    manager_pid, worker_pid = tmp_path / "manager", tmp_path / "worker"
    command = subprocess.Popen([sys.executable, "-c", ORPHANED, str(manager_pid), str(worker_pid)], cwd=ROOT)
    try:
        deadline = time.monotonic() + 60
        while not worker_pid.exists() and time.monotonic() < deadline and command.poll() is None:
            time.sleep(0.05)
        pids = [int(manager_pid.read_text()), int(worker_pid.read_text())]
        assert all(running(pid) for pid in pids)
    finally:
        command.kill()
        command.wait()
    deadline = time.monotonic() + 10 * workers.PARENT_CHECK_S
    while any(running(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(running(pid) for pid in pids)


def ctrl_c_ignored() -> bool:
    """A worker's job: whether SIGINT is ignored in its process."""
    return signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_pool_workers_start_deaf_to_ctrl_c():
    """A terminal's Ctrl-C reaches every process of the group: a worker leaves it to the process that started it
    (from its first instruction, so not even its start-up prints a traceback), which keeps its own handler."""
    handler = signal.getsignal(signal.SIGINT)
    with single_thread_processes(1) as pool:
        assert pool.submit(ctrl_c_ignored).result()
    assert signal.getsignal(signal.SIGINT) is handler


def test_a_signal_while_the_report_manager_starts_waits_for_its_start(monkeypatch):
    """Ctrl-C while the Manager's server starts is raised once it has started, and the server is shut down: given up
    halfway, it would write its address to no one, with a traceback."""
    start = workers._DeafProcess.start

    def start_then_ctrl_c(process) -> None:
        start(process)
        signal.raise_signal(signal.SIGINT)  # to this thread, now: Ctrl-C at this point

    monkeypatch.setattr(workers._DeafProcess, "start", start_then_ctrl_c)
    with pytest.raises(KeyboardInterrupt), report_manager():
        pytest.fail("the block ran")
    assert not multiprocessing.active_children()
