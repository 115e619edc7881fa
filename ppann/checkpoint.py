"""Checkpoints: weights, config, training history, input scaling and a fingerprint of the data,
in a file that `torch.load(weights_only=True)` reads (tensors, dicts, lists, strings, numbers)."""

from __future__ import annotations

import hashlib
import io
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch

from common.atomic import atomic_path
from common.errors import CrankError
from ppann.kinds import KINDS, MODEL_KINDS
from twin.dataset import Dataset
from twin.geometry import Geometry

FORMAT = "crank-ppann-checkpoint"
VERSION = 4
"""2: the PPANN carries machine_sigma (the machine-level spread of ppann/machine.py); 3: and what
the training machines leave open about the line (common_covariance, machine_profile)."""


OPTIONAL_BUFFERS = ("spread_machines", "spread_candidates", "spread_rise_tail", "spread_mean_tail")
"""Buffers added within VERSION, whose zeros mean "not recorded" (ppann/confidence.py: the
machines a spread was learnt from, since session 79; ppann/inversion.py: the bounds' calibration,
since session 81): an older checkpoint loads with zeros."""


class CheckpointError(CrankError, ValueError):
    """A file is not a checkpoint of this version and architecture."""


def fingerprint(dataset: Dataset) -> str:
    """sha256 over the measurement arrays a model was trained on."""
    digest = hashlib.sha256()
    for name in ("t", "episode", "theta", "omega", "tau"):
        digest.update(np.ascontiguousarray(getattr(dataset, name)).tobytes())
    return digest.hexdigest()


def save(path: str | Path, model: torch.nn.Module, *, kind: str, extra: dict[str, Any]) -> None:
    """Write a checkpoint atomically; `extra` holds history, train config, scaling, fingerprint.
    A model with a `geometry` (the PPANN) records it: the mechanism its slider is about."""
    if hasattr(model, "geometry"):
        extra = {**extra, "geometry": model.geometry.as_dict()}
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "kind": kind,
        "config": model.config.as_dict(),
        "state_dict": model.state_dict(),
        **extra,
    }
    buffer = io.BytesIO()  # saved from memory, the zip's folder is "archive", not the temp name,
    torch.save(payload, buffer)  # so the same weights give the same bytes (and ocp.json's hash)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buffer.getvalue())


def load(path: str | Path) -> tuple[torch.nn.Module, dict[str, Any]]:
    """Read a checkpoint: the model (eval mode) and the whole payload.

    Raises:
      CheckpointError: missing file, not a checkpoint, another version, another architecture.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, OSError) as exc:
        reason = str(exc)
        if "WeightsUnpickler error:" in reason:  # after torch's advice to load it unsafely
            reason = reason.split("WeightsUnpickler error:", 1)[1].strip().split("\n\n")[0]
        reason = " ".join(reason.split())[:160]
        raise CheckpointError(f"{path}: not a checkpoint, or a damaged one ({reason})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a {FORMAT} file")
    if payload.get("version") != VERSION:
        raise CheckpointError(
            f"{path}: checkpoint version {payload.get('version')!r}, this code reads {VERSION}"
        )
    if payload.get("kind") not in KINDS:
        raise CheckpointError(f"{path}: unknown model kind {payload.get('kind')!r}")
    try:
        config = dict(payload["config"])
        if payload["kind"] != "blackbox":  # saved before the option: the paper's architecture
            config.setdefault("sigma_speed", False)
            config.setdefault("machine_terms", "augmented")
        model = MODEL_KINDS[payload["kind"]].build(config)
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: config does not fit this architecture ({exc})") from None
    for name, tensor in payload["state_dict"].items():
        if torch.is_tensor(tensor) and tensor.is_floating_point() and not tensor.isfinite().all():
            raise CheckpointError(f"{path}: tensor {name!r} holds NaN or inf")
    state = dict(payload["state_dict"])
    for name, value in model.state_dict().items():  # recorded since: zeros read as before
        if name in OPTIONAL_BUFFERS:
            state.setdefault(name, torch.zeros_like(value))
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        reason = " ".join(str(exc).split())[:200]
        raise CheckpointError(f"{path}: weights from another architecture ({reason})") from None
    if hasattr(model, "geometry"):  # a checkpoint from before geometry was recorded: the paper's
        model.geometry = Geometry.from_dict(payload.get("geometry"), source=str(path))
    model.eval()
    return model, payload
