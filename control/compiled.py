"""CasADi functions compiled to C with the system's C compiler (CasADi's JIT), for the hot
paths that evaluate one model many times: the MPC's prediction (control/mpc.py) and, on
request, the OCP's NLP (control/ocp.py, `OCPConfig.compiled`).

Sources and libraries go to a temporary folder that lives as long as the object that owns it
(`Workshop`), never to the working folder: CasADi's `nlpsol` writes its generated source to the
working folder whatever its `directory` option says, so the build runs inside the folder
(`with workshop.building():`). CasADi's own clean-up is off, since it would run after the folder
is gone and warn. Without a C compiler CasADi raises RuntimeError, and the callers fall back to
its virtual machine.
"""

from __future__ import annotations

import contextlib
import tempfile
from collections.abc import Iterator
from typing import Any


class Workshop:
    """A temporary folder for one owner's compiled functions, and the CasADi options that put
    them there."""

    def __init__(self) -> None:
        self._folder = tempfile.TemporaryDirectory(prefix="crank-jit-")

    @contextlib.contextmanager
    def building(self) -> Iterator[None]:
        """Build (construct and first load) the compiled function inside the folder."""
        with contextlib.chdir(self._folder.name):
            yield

    @staticmethod
    def options(*, flags: tuple[str, ...] = ("-O1",)) -> dict[str, Any]:
        """CasADi function options: JIT with `flags`, no clean-up by CasADi."""
        return {
            "jit": True,
            "compiler": "shell",
            "jit_name": "crank_jit",
            "jit_temp_suffix": True,
            "jit_cleanup": False,
            "jit_options": {"flags": list(flags), "cleanup": False},
        }
