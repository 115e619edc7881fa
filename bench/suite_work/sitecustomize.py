"""Loaded at the start of every Python process of a `bench/suite_work.py` run (the pytest workers,
the `crank` subprocesses the tests start, Ray's workers): times the suite's heavy calls and logs
each as a JSON line to $CRANK_WORKLOG — what (dataset, training, OCP build, figure), a key of its
inputs (so that the same work done twice is seen), seconds, the test that ran it and the pid.

Each call is wrapped where its module is first imported (a finder ahead of the path's), so
callers that import the name later take the wrapper; nothing is wrapped unless $CRANK_WORKLOG is
set. The numbers of the calls are untouched: a wrapper times, hashes its inputs and returns.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.abc
import importlib.machinery
import json
import os
import sys
import time
from collections.abc import Callable
from typing import Any

LOG = os.environ.get("CRANK_WORKLOG")


def _short(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def _file(path: Any) -> str:
    try:
        with open(path, "rb") as f:
            return hashlib.sha256(f.read()).hexdigest()[:12]
    except OSError:
        return "?"


def _dataset(config: Any, **options: Any) -> str:
    from twin import MODEL_PATH  # generate_file's default, wherever the process runs

    return f"{_short(repr(config))}/{_file(options.get('model_path', MODEL_PATH))}"


def _training(data_path: Any, out: Any, **options: Any) -> str:
    import torch

    return f"{_file(data_path)}/{_short(repr(options.get('config')))}/{torch.get_num_threads()}"


def _build(nlp: Any, options: Any, **_: Any) -> str:
    from control.solvers import nlp_key

    return nlp_key(nlp, options)[:12]


def _figure(fig: Any, path: Any) -> str:
    return os.path.basename(str(path))


WRAPPED: dict[str, tuple[str, str, Callable[..., str]]] = {
    "twin.generation": ("generate_file", "dataset", _dataset),
    "ppann.pipeline": ("train_and_report", "training", _training),
    "control.solvers": ("build", "ocp build", _build),
    "common.figures": ("save_figure", "figure", _figure),
}


def _wrap(module: Any, name: str, what: str, key: Callable[..., str]) -> None:
    inner = getattr(module, name)

    @functools.wraps(inner)
    def timed(*args: Any, **kwargs: Any) -> Any:
        try:  # before the call: CasADi serialises an NLP otherwise once nlpsol was built on it
            inputs = key(*args, **kwargs)
        except Exception as error:  # a key that fails is logged as such
            inputs = f"? {error}"
        started = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            seconds = time.perf_counter() - started
            test = os.environ.get("PYTEST_CURRENT_TEST", "").split(" ")[0]
            line = {"what": what, "key": inputs, "s": seconds, "test": test, "pid": os.getpid()}
            with open(LOG, "a") as log:  # one short line per write: lines from processes stay whole
                log.write(json.dumps(line) + "\n")

    setattr(module, name, timed)


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname: str, path: Any, target: Any = None) -> Any:
        if fullname not in WRAPPED:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path)
        if spec is None or spec.loader is None:
            return spec
        run = spec.loader.exec_module

        def exec_module(module: Any) -> None:
            run(module)
            _wrap(module, *WRAPPED[fullname])

        spec.loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


if LOG:
    sys.meta_path.insert(0, _Finder())
