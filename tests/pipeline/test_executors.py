"""`cnep evaluate --executor dask|ray ADDRESS`: a malformed address is one line and exit 2 before anything runs, and an
address where no scheduler answers (nothing listening, a listener that never says a word, an HTTP server) is one line
and exit 2 within the connection's time limit, not a run that waits for good. Listeners on 127.0.0.1 only."""

import contextlib
import http.server
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from cnep.pipeline.cli.main import main
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.evaluate import addresses
from cnep.pipeline.evaluate.stage import EvaluateConfig

LIMIT_S = 1.0  # the connection's time limit in these tests


@pytest.fixture(autouse=True)
def short_limit(monkeypatch):
    monkeypatch.setattr(addresses, "CONNECT_SECONDS", LIMIT_S)


@contextlib.contextmanager
def silent_listener() -> Iterator[int]:
    """A port on 127.0.0.1 that accepts connections and never sends a byte."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        accepted: list[socket.socket] = []
        server.settimeout(0.1)

        def accept() -> None:
            while not done.is_set():
                with contextlib.suppress(OSError):
                    accepted.append(server.accept()[0])

        done = threading.Event()
        thread = threading.Thread(target=accept, daemon=True)
        thread.start()
        try:
            yield server.getsockname()[1]
        finally:
            done.set()
            thread.join()
            for conn in accepted:
                conn.close()


@contextlib.contextmanager
def http_server() -> Iterator[int]:
    """A port on 127.0.0.1 where a tiny HTTP server answers."""
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()


def closed_port() -> int:
    """A port on 127.0.0.1 where nothing listens."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def evaluate_on(address: str, tmp_path, capsys) -> tuple[int, list[str], float]:
    """`cnep evaluate --quick` on a Dask cluster at `address`: exit status, stderr lines, seconds taken."""
    capsys.readouterr()
    start = time.monotonic()
    argv = ["-q", "evaluate", "--quick", "--no-figures", "--executor", "dask", address, "--out", str(tmp_path / "e")]
    code = main(argv)
    return code, capsys.readouterr().err.strip().splitlines(), time.monotonic() - start


@pytest.mark.parametrize(
    "listener, says",
    [
        (silent_listener, "sent no Dask handshake within 1.0 s: it is not a Dask scheduler"),
        (http_server, "sent no Dask handshake within 1.0 s: it is not a Dask scheduler"),
    ],
    ids=["silent", "http"],
)
def test_a_port_where_no_scheduler_answers_is_one_line_within_the_limit(tmp_path, capsys, listener, says):
    pytest.importorskip("distributed")
    with listener() as port:
        address = f"tcp://127.0.0.1:{port}"
        code, err, took = evaluate_on(address, tmp_path, capsys)
    assert code == 2 and len(err) == 1 and f"--executor dask {address}" in err[0] and says in err[0], err
    assert took < 30 * LIMIT_S, took  # the command's own start-up, then one limit; it waited for good before
    assert not (tmp_path / "e").exists()


def test_nothing_listening_is_one_line(tmp_path, capsys):
    pytest.importorskip("distributed")
    address = f"tcp://127.0.0.1:{closed_port()}"
    code, err, _ = evaluate_on(address, tmp_path, capsys)
    assert code == 2 and len(err) == 1 and f"--executor dask {address}: cannot connect" in err[0], err


def test_the_probe_tells_a_scheduler_from_other_listeners():
    """A real scheduler passes (its handshake's length), an HTTP reply does not (read as a length: 3 EiB)."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]

        def answer(reply: bytes) -> None:
            conn, _ = server.accept()
            with conn:
                conn.sendall(reply)
                time.sleep(0.2)

        for reply, refused in [((100).to_bytes(8, "little") + bytes(100), False), (b"HTTP/1.0 400 Bad", True)]:
            thread = threading.Thread(target=answer, args=(reply,))
            thread.start()
            try:
                if refused:
                    with pytest.raises(PipelineError, match="answered 'HTTP/1.0', not a Dask scheduler's handshake"):
                        addresses.reach("dask", f"tcp://127.0.0.1:{port}")
                else:
                    addresses.reach("dask", f"127.0.0.1:{port}")
            finally:
                thread.join()


@pytest.mark.parametrize(
    "executor, address, says",
    [
        ("dask", "tcp://127.0.0.1", "no port"),
        ("dask", "127.0.0.1", "no port"),
        ("dask", "tcp://:8786", "no host"),
        ("dask", "tcp://host:port", "port 'port' is not a number from 1 to 65535"),
        ("dask", "tcp://host:99999", "port '99999' is not a number from 1 to 65535"),
        ("dask", "http://host:8786", "scheme 'http'"),
        ("dask", "tcp://host:8786/path", "no port"),
        ("dask", f"tcp://{'a' * 64}:8786", "is not a host name or IP address"),
        ("dask", "tcp://a..b:8786", "is not a host name or IP address"),
        ("ray", "ray://host", "no port"),
    ],
)
def test_a_malformed_address_is_one_line_before_anything_runs(tmp_path, capsys, executor, address, says):
    with pytest.raises(PipelineError, match=f"--executor {executor} {address}: .*{says}"):
        EvaluateConfig(executor=executor, address=address)
    capsys.readouterr()
    assert main(["-q", "evaluate", "--executor", executor, address, "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0], err
    assert not (tmp_path / "e").exists()


@pytest.mark.parametrize(
    "address", ["tcp://scheduler:8786", "scheduler:8786", "tls://10.0.0.5:8786", "[::1]:8786", f"{'a' * 63}.b:1"]
)
def test_a_well_formed_dask_address_is_taken(address):
    assert EvaluateConfig(executor="dask", address=address).address == address


def test_a_dask_scheduler_passes_the_probe():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=0, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        addresses.reach("dask", cluster.scheduler_address)


def test_a_dask_cluster_runs_any_units_function():
    """The executors hand each unit to the function they are given (`cnep evaluate`'s jobs, `cnep sim grid`'s units)."""
    distributed = pytest.importorskip("distributed")
    from cnep.pipeline.evaluate.executors import run_on_cluster

    with distributed.LocalCluster(
        n_workers=1, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        done = sorted(run_on_cluster(str.upper, ["a", "b"], "dask", cluster.scheduler_address, workers=1))
    assert done == [("a", "A"), ("b", "B")]
