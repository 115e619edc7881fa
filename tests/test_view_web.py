"""`crank view FILE.rrd --web`: the Rerun web viewer bundled with rerun-sdk, served on localhost
with the recording (no display, no download), stopped by Ctrl-C or `kill`."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from tests.conftest import crank


def _free_port() -> int:
    for port in range(19_100, 19_900, 2):
        with socket.socket() as a, socket.socket() as b:
            if a.connect_ex(("127.0.0.1", port)) and b.connect_ex(("127.0.0.1", port + 1)):
                return port
    raise AssertionError("no two free ports")


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "kill"])
def test_web_viewer_serves_the_recording_until_interrupted(
    ocp_path: Path,
    tmp_path: Path,
    stop: signal.Signals,
) -> None:
    """Served until stopped; the viewer stops with it, also where SIGINT was inherited ignored
    (a background job of a non-interactive shell: before, Ctrl-C then never reached it)."""
    out = tmp_path / "replay.mcap"
    assert crank("replay", "--ocp", str(ocp_path), "--out", str(out), "--runs", "2").returncode == 0
    port = _free_port()
    view = ["view", str(out.with_suffix(".rrd")), "--web", "--port", str(port)]
    server = subprocess.Popen(
        [sys.executable, "-m", "crank", *view],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    try:
        page, deadline = None, time.monotonic() + 60
        while page is None:
            assert server.poll() is None, server.stderr.read() if server.stderr else ""
            assert time.monotonic() < deadline, "the web viewer did not answer in 60 s"
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=2) as response:
                    page = response.read().decode()
            except OSError:
                time.sleep(0.3)
        assert "Rerun SDK-bundled web viewer" in page
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/re_viewer_bg.wasm") as wasm:
            assert len(wasm.read()) > 10_000_000  # the viewer itself, served from the wheel
        with socket.socket() as data:  # the recording's gRPC proxy, on the next port
            assert data.connect_ex(("127.0.0.1", port + 1)) == 0
        taken = crank(*view)
        assert taken.returncode == 2 and f"port {port} is in use" in taken.stderr
    finally:
        server.send_signal(stop)
        stdout, _ = server.communicate(timeout=30)
    assert server.returncode == 0
    with socket.socket() as gone:  # the viewer stopped with it
        assert gone.connect_ex(("127.0.0.1", port)) != 0
    assert f"http://127.0.0.1:{port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{port + 1}" in stdout
