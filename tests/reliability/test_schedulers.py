"""A --scheduler address is checked before any work: one line for an empty address, a
file, no port, an unreachable host, a server that is not a Dask scheduler; a real
scheduler passes (issue 54: silent for 200 s, a Client.__del__ traceback, 250 lines of
Rich traceback, "Unable to allocate 3.07 EiB", a silent local run)."""

from __future__ import annotations

import http.server
import socket
import threading
from pathlib import Path

import pytest
from typer.testing import CliRunner

from pipeline.apps.cli import app
from pipeline.config import ConfigError
from pipeline.engine.tracetasks import check_scheduler

ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("address, words", [
    ("", "empty address"),
    ("   ", "empty address"),
    ("localhost", "expected tcp://host:port"),
    ("http://localhost:8786", "expected tcp://host:port"),
])
def test_malformed_addresses_are_one_line(address, words):
    with pytest.raises(ConfigError, match=words) as exc:
        check_scheduler(address)
    assert "\n" not in str(exc.value)


def test_a_file_unreachable_port_and_a_web_server_are_named(tmp_path, monkeypatch):
    f = tmp_path / "sched.txt"
    f.write_text("tcp://somewhere:8786")
    with pytest.raises(ConfigError, match="a path on this machine"):
        check_scheduler(str(f))
    with pytest.raises(ConfigError, match="unreachable"):
        check_scheduler(f"tcp://127.0.0.1:{_free_port()}")
    import pipeline.engine.tracetasks as tt

    monkeypatch.setattr(tt, "HANDSHAKE_TIMEOUT_S", 3.0)  # the bound, not its size, is under test
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        with pytest.raises(ConfigError, match="not a Dask scheduler") as exc:
            check_scheduler(f"127.0.0.1:{server.server_address[1]}")
        assert "\n" not in str(exc.value)
    finally:
        server.shutdown()


def test_a_real_scheduler_passes():
    from distributed import LocalCluster

    with LocalCluster(n_workers=0, processes=False, protocol="tcp", dashboard_address=None) as cluster:
        assert check_scheduler(cluster.scheduler_address) == cluster.scheduler_address


def test_the_cli_refuses_before_any_work(tmp_path):
    out = tmp_path / "sweep"
    res = CliRunner().invoke(app, ["sweep", str(ROOT / "configs" / "sweep_example.toml"), "--out",
                                   str(out), "--scheduler", ""])
    assert res.exit_code == 2 and "empty address" in res.output and "Traceback" not in res.output
    assert len(res.output.strip().splitlines()) <= 2 and not (out / "runs").exists()
