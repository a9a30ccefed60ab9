"""Fresh `python -m MODULE ...` processes without paying for torch each time: a server process imports the third-party
libraries a `cnep` command loads (torch, torchvision, OpenCV, ONNX; not ONNX Runtime or rerun, which start threads
when imported) and forks one child per request, which then runs the module as `python -m` would, cnep included,
and ends through the interpreter's own exit (exit handlers and all). The fault tests kill these children
(tests/pipeline/test_faults.py); each is a process of its own with its pid, its pipes and its exit status.

    server = Preloaded()
    child = server.popen([sys.executable, "-m", "tests.pipeline.fault_driver", ...], cwd=ROOT, env=env)
    child.send_signal(signal.SIGTERM); out, err = child.communicate(timeout=60); child.returncode
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading

PRELOAD = ("numpy", "torch", "torchvision", "cv2", "mcap", "onnx")
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


class Child:
    """A forked process as subprocess.Popen shows one: pid, stdout and stderr (text pipes), returncode (negative:
    the signal that ended it), send_signal, kill, wait, communicate."""

    def __init__(self, pid: int, stdout: int, stderr: int, status: int):
        self.pid, self.returncode = pid, None
        self.stdout, self.stderr = open(stdout), open(stderr)  # noqa: SIM115 (closed by communicate)
        self._status = status  # the server writes the exit status here, then closes it

    def send_signal(self, signum: int) -> None:
        if self.returncode is None:
            with contextlib.suppress(ProcessLookupError):  # it ended meanwhile
                os.kill(self.pid, signum)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)

    def wait(self, timeout: float | None = None) -> int:
        if self.returncode is None:
            ready, _, _ = select.select([self._status], [], [], timeout)
            if not ready:
                raise subprocess.TimeoutExpired(str(self.pid), timeout)
            self.returncode = int(os.read(self._status, 64))
            os.close(self._status)
        return self.returncode

    def communicate(self, timeout: float | None = None) -> tuple[str, str]:
        """Read both pipes to their end, then wait; (stdout, stderr)."""
        err: list[str] = []
        reader = threading.Thread(target=lambda: err.append(self.stderr.read()), daemon=True)
        reader.start()
        out = self.stdout.read()
        reader.join(timeout)
        if reader.is_alive():
            raise subprocess.TimeoutExpired(str(self.pid), timeout)
        self.stdout.close()
        self.stderr.close()
        self.wait(timeout)
        return out, err[0]


class Preloaded:
    """The server (`python -m tests.pipeline.preloaded`), started at once; `popen` forks a child of it."""

    def __init__(self):
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.server = subprocess.Popen(
            [sys.executable, "-m", "tests.pipeline.preloaded", str(theirs.fileno())],
            pass_fds=[theirs.fileno()],
            cwd=ROOT,
            env={**os.environ, "PYTHONPATH": ROOT},
        )
        theirs.close()
        self.socket = ours

    def popen(self, argv: list[str], cwd: str, env: dict[str, str]) -> Child:
        """A child that runs `argv` (`[python, "-m", MODULE, *args]`) in `cwd` with the environment `env`."""
        assert argv[1] == "-m", argv
        pipes = [os.pipe() for _ in range(3)]  # stdout, stderr, exit status: (read, write) each
        request = json.dumps({"argv": argv[2:], "cwd": str(cwd), "env": env}).encode()
        socket.send_fds(self.socket, [request], [w for _, w in pipes])
        for _, w in pipes:
            os.close(w)
        return Child(int(self.socket.recv(64)), *(r for r, _ in pipes))

    def close(self) -> None:
        self.socket.close()  # the server ends when its socket does
        self.server.wait(timeout=60)


def serve(server: socket.socket) -> list[str] | None:
    """Fork a child per request until the socket closes (then the children left are killed), reaping each child and
    writing its exit status to its status pipe; in a child, return the request's argv (`[MODULE, *args]`); in the
    server, None at the end."""
    children: dict[int, int] = {}  # pid -> status pipe
    while True:
        reap(children, block=False)
        ready, _, _ = select.select([server], [], [], 0.05)
        if not ready:
            continue
        message, fds, _, _ = socket.recv_fds(server, 1 << 20, 3)
        if not message:  # the tests are done: a child still running was left behind by a failed one
            for pid in children:
                os.kill(pid, signal.SIGKILL)
            reap(children, block=True)
            return None
        request = json.loads(message)
        pid = os.fork()
        if pid == 0:
            server.close()
            for status in children.values():
                os.close(status)
            become(request, *fds)
            return request["argv"]
        os.close(fds[0])
        os.close(fds[1])
        children[pid] = fds[2]
        server.send(str(pid).encode())


def become(request: dict, stdout: int, stderr: int, status: int) -> None:
    """In a fresh child: the request's pipes as stdout and stderr, nothing on stdin, its folder and environment."""
    os.close(status)
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(stdout, 1)
    os.dup2(stderr, 2)
    os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
    os.close(stdout)
    os.close(stderr)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])


def reap(children: dict[int, int], block: bool) -> None:
    """Write the exit status of every child that ended (all of them with `block`) to its status pipe."""
    while children:
        pid, status = os.waitpid(-1, 0 if block else os.WNOHANG)
        if pid == 0:
            return
        if pid in children:
            fd = children.pop(pid)
            with contextlib.suppress(BrokenPipeError):  # nobody waits for it any more
                os.write(fd, str(os.waitstatus_to_exitcode(status)).encode())
            os.close(fd)


if __name__ == "__main__":
    import runpy

    for name in PRELOAD:
        importlib.import_module(name)
    # what the libraries made is kept out of the cyclic collector's passes: a child's collections, its exit's above
    # all, would otherwise walk every object torch made and copy the pages they are on
    gc.freeze()
    argv = serve(socket.socket(fileno=int(sys.argv[1])))
    if argv is None:
        sys.exit(0)
    sys.argv = argv
    runpy.run_module(argv[0], run_name="__main__", alter_sys=True)
