"""`crank view`: a campaign's Rerun recording in the viewer, in the browser (`--web`, the web
viewer rerun-sdk bundles) or, where there is no display, how to open it (registered on the app by
crank/cli.py's `main`; a bad input is one line on stderr and exit code 2)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import Annotated
from urllib.parse import quote

import typer

from common.atomic import OutputError
from common.errors import ConfigError
from crank.console import app, one_line_errors


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or (
        sys.platform in ("darwin", "win32")
    )


WEB_PORT = 9090


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _serve_web(path: Path, port: int) -> None:
    """The Rerun web viewer of `path` on localhost, in the foreground until Ctrl-C or kill."""
    for taken in (port, port + 1):
        with socket.socket() as probe:
            if probe.connect_ex(("127.0.0.1", taken)) == 0:
                raise ConfigError(f"port {taken} is in use here: choose another --port")
    command = [sys.executable, "-m", "rerun", "--serve-web", "--bind", "127.0.0.1"]
    command += ["--web-viewer-port", str(port), "--port", str(port + 1), str(path)]
    data = quote(f"rerun+http://127.0.0.1:{port + 1}/proxy", safe="")
    typer.echo(f"serving {path}: open http://127.0.0.1:{port}/?url={data} (Ctrl-C stops)")
    quiet = os.environ | {"RUST_LOG": "warn"}  # the viewer's own INFO lines
    # Ctrl-C and `kill` both stop the viewer: a process started in the background by a
    # non-interactive shell inherits SIGINT ignored (Python then never raises
    # KeyboardInterrupt), and SIGTERM would end this process and leave the viewer running
    previous = {sig: signal.signal(sig, _interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        # `python -m rerun` runs the viewer binary as its own child: a session of their own,
        # so that stopping here stops both and leaves nothing behind
        server = subprocess.Popen(
            command, stdout=subprocess.DEVNULL, env=quiet, start_new_session=True
        )
        try:
            code = server.wait()
        except KeyboardInterrupt:
            os.killpg(server.pid, signal.SIGTERM)
            server.wait()
            return
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if code != 0:
        raise OutputError(f"the Rerun web viewer stopped with exit code {code}")


@app.command("view", short_help="Open a recording in the Rerun viewer.")
@one_line_errors
def view_command(
    path: Annotated[Path, typer.Argument(help="A campaign's .rrd (or an .mcap log).")],
    web: Annotated[
        bool,
        typer.Option(
            help="Serve the Rerun web viewer (bundled with rerun-sdk, no download) with the "
            "recording on http://127.0.0.1:PORT until Ctrl-C; needs no display."
        ),
    ] = False,
    port: Annotated[
        int, typer.Option(help="Port of --web's viewer page (its data port is the next one).")
    ] = WEB_PORT,
) -> None:
    """Open a recording in the Rerun viewer, or say how to open it where there is no display."""
    from replay.recording import check_recording, rerun_version

    if not 1024 <= port <= 65534:
        raise ConfigError(f"--port must be in 1024..65534, got {port}")
    if not path.is_file():
        raise OutputError(f"file not found: {path}")
    if path.suffix == ".mcap":
        typer.echo(
            f"{path} is an MCAP log: open it in Foxglove (Open local file), or view the "
            f"Rerun recording beside it: crank view {path.with_suffix('.rrd')}"
        )
        return
    if path.suffix != ".rrd":
        raise OutputError(f"crank view opens .rrd recordings (or names .mcap logs), got {path}")
    check_recording(path)
    if web:
        _serve_web(path, port)
        return
    if not _has_display():
        typer.echo(
            f"no display here: copy {path} to a machine with a display and run "
            f"`rerun {path.name}` (rerun-sdk {rerun_version()}), or drop it on the Rerun "
            "web viewer of the same version"
        )
        return
    subprocess.Popen([sys.executable, "-m", "rerun", str(path)], start_new_session=True)
    typer.echo(f"opened {path} in the Rerun viewer")
