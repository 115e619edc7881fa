"""The suite's `crank` commands, each in its own process forked from a server that imported the
heavy libraries once.

A `crank` command that trains, solves or replays spends ~4-7 s of a 2-core machine importing
torch, CasADi, MuJoCo, SciPy and matplotlib before it does anything; the suite starts ~100 `crank`
commands. The server (one per test process, started at its first command) imports those
libraries, and no module of the project, then forks a child per command: the child takes the
command's working directory, environment, stdout and stderr, runs `python -m crank ARGS` as the
interpreter would (`runpy`; SystemExit's code, or an uncaught exception's traceback and exit 1;
then its threads joined and its exit handlers run) and leaves with `os._exit`. Each command is
still its own process, with its own exit code, file descriptors and signals (a test may SIGKILL
it), and the project's code imported afresh in it; what it shares with the others is only the
libraries' import-time state (and the hash seed). Rerun is not preloaded (importing it starts
threads, which a fork does not carry), nor Ray.

A test that checks what a command imports runs a real interpreter (tests/test_outputs.py), and
$CRANK_TEST_FORKSERVER=0 runs every command in one (tests/conftest.py `start_crank`).

Protocol, over a Unix socket pair: the client sends one JSON request (argv, cwd, environment)
with the child's stdout and stderr descriptors (SCM_RIGHTS); the server answers
`{"pid": N}` once forked, then `{"pid": N, "status": S}` once the child has ended (S as
`subprocess`'s returncode: the exit code, or minus the signal).
"""

from __future__ import annotations

import atexit
import json
import os
import runpy
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

PRELOAD = (
    "numpy",
    "torch",
    "casadi",
    "mujoco",
    "scipy.stats",
    "scipy.special",
    "matplotlib.figure",
    "matplotlib.backends.backend_agg",
    "mcap.reader",
    "mcap.writer",
    "typer",
)
"""Imported by the server before it forks (~4 s of the ~5 s a training command's imports take;
the project's own modules and what they import besides are imported in each child)."""

_MAX_FDS = 2
_BUFFER = 1 << 20


def _child(request: dict[str, Any], out: int, err: int) -> None:
    """Run in the forked child: become `python -m crank ARGS` and leave with its exit code."""
    code: int = 0
    try:
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(out, 1)
        os.dup2(err, 2)
        for fd in (null, out, err):
            os.close(fd)
        if request["new_session"]:
            os.setsid()
        os.chdir(request["cwd"])
        sys.path[0] = os.getcwd()  # as `python -m` puts it
        os.environ.clear()
        os.environ.update(request["env"])
        sys.argv = ["crank", *request["args"]]
        try:
            runpy.run_module("crank", run_name="__main__", alter_sys=True)
        except SystemExit as exit:
            if exit.code is None:
                code = 0
            elif isinstance(exit.code, int):
                code = exit.code
            else:
                print(exit.code, file=sys.stderr)
                code = 1
    except BaseException:
        traceback.print_exc()
        code = 1
    finally:
        # the interpreter's own ending: wait for threads that are not daemons, run the exit
        # handlers (Ray's shutdown, Rerun's flush), flush stdout and stderr
        threading._shutdown()  # type: ignore[attr-defined]
        atexit._run_exitfuncs()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                code = code or 120
        os._exit(code)


def serve(sock: socket.socket) -> None:
    """The server's loop: one request at a time; a waiter thread per child reports its end."""
    for name in PRELOAD:
        __import__(name)
    send_lock = threading.Lock()

    def send(message: dict[str, Any]) -> None:
        with send_lock:
            sock.sendall(json.dumps(message).encode())

    def wait(pid: int) -> None:
        _, status = os.waitpid(pid, 0)
        send({"pid": pid, "status": os.waitstatus_to_exitcode(status)})

    send({"ready": True})
    while True:
        data, fds, _, _ = socket.recv_fds(sock, _BUFFER, _MAX_FDS)
        if not data:
            return
        request = json.loads(data)
        pid = os.fork()
        if pid == 0:
            sock.close()
            _child(request, *fds)
        for fd in fds:
            os.close(fd)
        send({"pid": pid})
        threading.Thread(target=wait, args=(pid,), daemon=True).start()


def _outputs() -> tuple[Any, Any]:
    """Two anonymous files for a command's stdout and stderr (closed by `communicate`)."""
    return tempfile.TemporaryFile(), tempfile.TemporaryFile()


class Command:
    """A `crank` command running in a process of its own (a child of the server, or a fresh
    interpreter): the few methods of `subprocess.Popen` the suite uses (pid, poll, wait, kill)
    and, once it has ended, its output. `status(timeout)` is its exit status, None while it
    runs `timeout` s on (0: at once; None: waits)."""

    def __init__(
        self,
        args: list[str],
        pid: int,
        out: Any,
        err: Any,
        *,
        status: Callable[[float | None], int | None],
    ) -> None:
        self.args = args
        self.pid = pid
        self.returncode: int | None = None
        self._out, self._err = out, err
        self._status = status

    def poll(self) -> int | None:
        if self.returncode is None:
            self.returncode = self._status(0.0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        """The exit status; `subprocess.TimeoutExpired` after `timeout` seconds."""
        if self.returncode is None:
            self.returncode = self._status(timeout)
            if self.returncode is None:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        return self.returncode

    def kill(self) -> None:
        if self.poll() is None:
            os.kill(self.pid, signal.SIGKILL)

    def communicate(self, timeout: float | None = None) -> subprocess.CompletedProcess[str]:
        """Wait (killing it after `timeout` s, as `subprocess.run` does) and read its output."""
        try:
            code = self.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            self.wait()
            raise
        texts = []
        for stream in (self._out, self._err):
            stream.seek(0)
            texts.append(stream.read().decode(errors="replace"))
            stream.close()
        return subprocess.CompletedProcess(self.args, code, texts[0], texts[1])


class ForkServer:
    """The client end: starts the server (a fresh interpreter) and asks it for commands."""

    def __init__(self) -> None:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self._process = subprocess.Popen(
            [sys.executable, "-m", "tests.forkserver", str(theirs.fileno())],
            pass_fds=(theirs.fileno(),),
            cwd=Path(__file__).resolve().parent.parent,
            stdin=subprocess.DEVNULL,
        )
        theirs.close()
        self._sock = ours
        self._ended: dict[int, int] = {}
        if self._read(timeout=None) != {"ready": True}:
            raise RuntimeError("the fork server did not start")

    def _read(self, *, timeout: float | None) -> dict[str, Any] | None:
        """The server's next message; None if none came within `timeout` s (None: wait)."""
        self._sock.settimeout(timeout)
        try:
            data = self._sock.recv(_BUFFER)
        except (BlockingIOError, TimeoutError):
            return None
        finally:
            self._sock.settimeout(None)
        if not data:
            raise RuntimeError(f"the fork server ended (exit {self._process.poll()})")
        return json.loads(data)

    def _receive(self, *, timeout: float | None) -> dict[str, Any] | None:
        """`_read`, keeping the exit status the message brings (of any child)."""
        message = self._read(timeout=timeout)
        if message is not None and "status" in message:
            self._ended[message["pid"]] = message["status"]
        return message

    def start(
        self,
        args: list[str],
        *,
        cwd: Path | None = None,
        env: dict[str, str] | None = None,
        new_session: bool = False,
    ) -> Command:
        """Fork `crank ARGS` in `cwd` with `env` (by default this process's), in a session of
        its own if asked (`subprocess.Popen`'s start_new_session)."""
        out, err = _outputs()
        request = {
            "args": args,
            "cwd": str(cwd or os.getcwd()),
            "env": dict(os.environ if env is None else env),
            "new_session": new_session,
        }
        socket.send_fds(self._sock, [json.dumps(request).encode()], [out.fileno(), err.fileno()])
        message = self._receive(timeout=None)
        while message is not None and "status" in message:  # another child's end, kept
            message = self._receive(timeout=None)
        assert message is not None
        pid = message["pid"]
        return Command(args, pid, out, err, status=lambda t: self.status(pid, timeout=t))

    def status(self, pid: int, *, timeout: float | None) -> int | None:
        """The exit status of child `pid`; None if it still runs after `timeout` s."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while pid not in self._ended:
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            if self._receive(timeout=left) is None:
                return None
        return self._ended.pop(pid)

    def close(self) -> None:
        self._sock.close()
        self._process.wait(timeout=30)


class Fresh:
    """Each command in a fresh interpreter (`python -m crank`), as `ForkServer.start` is asked:
    $CRANK_TEST_FORKSERVER=0 runs the suite so."""

    def start(
        self,
        args: list[str],
        *,
        cwd: Path | None = None,
        env: dict[str, str] | None = None,
        new_session: bool = False,
    ) -> Command:
        out, err = _outputs()
        process = subprocess.Popen(
            [sys.executable, "-m", "crank", *args],
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=err,
            start_new_session=new_session,
        )

        def status(timeout: float | None) -> int | None:
            if timeout == 0.0:
                return process.poll()
            try:
                return process.wait(timeout)
            except subprocess.TimeoutExpired:
                return None

        return Command(args, process.pid, out, err, status=status)

    def close(self) -> None:
        pass


if __name__ == "__main__":
    serve(socket.socket(fileno=int(sys.argv[1])))
