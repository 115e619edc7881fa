"""Fit a model of one kind (ppann/kinds.py) on a dataset: the PPANN in two phases, a baseline in
phase 1 only; several kinds one after another or side by side (`fit_all`)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from dataclasses import asdict, dataclass, replace

import torch

from common.streams import torch_seed
from ppann.kinds import model_kind
from ppann.model import PPANNConfig
from ppann.plan_fit import fit_plan_episodes, plan_episodes
from ppann.train import History, Splits, make_splits, train_mean, train_sigma
from ppann.train_config import TrainConfig
from ppann.transmission import fit_quantiles
from twin.dataset import Dataset


@dataclass
class Fitted:
    kind: str
    model: torch.nn.Module
    history: History
    seconds: float


def fit(
    dataset: Dataset,
    *,
    kind: str,
    config: TrainConfig,
    splits: Splits | None = None,
    ppann_config: PPANNConfig | None = None,
    on_epoch: Callable[[str, int, float], None] | None = None,
) -> Fitted:
    """Train a model of `kind`; `on_epoch(phase, epoch, loss)` reports progress."""
    splits = splits or make_splits(dataset, config)
    model = new_model(dataset, kind=kind, config=config, ppann_config=ppann_config)
    return train_model(model, dataset, kind=kind, config=config, splits=splits, on_epoch=on_epoch)


def fit_all(
    dataset: Dataset,
    *,
    kinds: Sequence[str],
    config: TrainConfig,
    splits: Splits,
    workers: int = 1,
    on_epoch: Callable[[str, str, int, float], None] | None = None,
    on_done: Callable[[str], None] | None = None,
) -> dict[str, Fitted]:
    """Every kind's `fit` with torch on one thread, the same to the last bit whether one after
    another or, with `workers` > 1, side by side in threads: the networks are small, so two of
    them on a core each train faster than one on both (torch's second thread gains ~1.4x). One
    thread also when one after another: torch splits its sums and products by its thread count,
    and on an AVX-512 machine (session 23) a model trained alone on two threads differed in its
    last bits from the same model trained on one, so a model depended on the cores that trained
    it. The models are built (seeded) here, before any training starts; training draws from
    its own generators only. `on_epoch(kind, phase, epoch, loss)` and `on_done(kind)` (its
    training has ended) may then come from any thread, one call at a time."""
    models = {kind: new_model(dataset, kind=kind, config=config) for kind in kinds}
    lock = threading.Lock()
    stop = threading.Event()  # one kind failed (or Ctrl-C): the others end at their next epoch

    def report(kind: str) -> Callable[[str, int, float], None]:
        def locked(phase: str, epoch: int, loss: float) -> None:
            if stop.is_set():
                raise _StoppedError
            if on_epoch is not None:
                with lock:
                    on_epoch(kind, phase, epoch, loss)

        return locked

    def train(kind: str) -> Fitted:
        fitted = train_model(
            models[kind], dataset, kind=kind, config=config, splits=splits, on_epoch=report(kind)
        )
        if on_done is not None:
            with lock:
                on_done(kind)
        return fitted

    threads = torch.get_num_threads()

    def pinned(kind: str) -> Fitted:
        torch.set_num_threads(1)  # a thread Python started keeps its own OpenMP setting
        return train(kind)

    torch.set_num_threads(1)
    try:
        if workers <= 1 or len(kinds) <= 1:
            return {kind: train(kind) for kind in kinds}
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = {kind: pool.submit(pinned, kind) for kind in kinds}
            try:
                done, _ = wait(futures.values(), return_when=FIRST_EXCEPTION)
                failed = next((f for f in done if f.exception() is not None), None)
                if failed is not None:
                    failed.result()  # raises the first failure
                return {kind: future.result() for kind, future in futures.items()}
            except BaseException:
                stop.set()  # else leaving the pool would wait for the others to finish
                pool.shutdown(wait=False, cancel_futures=True)  # and start the queued ones
                raise
    finally:
        torch.set_num_threads(threads)


class _StoppedError(Exception):
    """Ends a kind's training in fit_all once another kind has failed."""


def new_model(
    dataset: Dataset, *, kind: str, config: TrainConfig, ppann_config: PPANNConfig | None = None
) -> torch.nn.Module:
    """A fresh model of `kind` from the training seed, on the dataset's geometry."""
    torch.manual_seed(torch_seed(config.seed, "training"))
    spec = model_kind(kind)
    if kind == "ppann" and config.sigma_wrap:  # asked for in the training config
        ppann_config = replace(ppann_config or PPANNConfig(), sigma_wrap=True)
    if kind == "ppann" and config.sigma_lever:
        ppann_config = replace(ppann_config or PPANNConfig(), sigma_lever=True)
    if kind == "ppann" and config.mean_wrap:
        ppann_config = replace(ppann_config or PPANNConfig(), mean_wrap=True)
    if kind == "ppann" and config.coulomb:
        ppann_config = replace(ppann_config or PPANNConfig(), coulomb=True)
    if kind == "ppann" and config.machine_terms != PPANNConfig.machine_terms:
        ppann_config = replace(ppann_config or PPANNConfig(), machine_terms=config.machine_terms)
    if kind == "ppann" and config.white_inertia != PPANNConfig.white_inertia:
        ppann_config = replace(ppann_config or PPANNConfig(), white_inertia=config.white_inertia)
    if kind == "ppann" and config.angle_update != PPANNConfig.angle_update:
        ppann_config = replace(ppann_config or PPANNConfig(), angle_update=config.angle_update)
    model = spec.new(ppann_config if kind == "ppann" else None)
    if hasattr(model, "geometry"):
        model.geometry = dataset.geometry
    return model


def train_model(
    model: torch.nn.Module,
    dataset: Dataset,
    *,
    kind: str,
    config: TrainConfig,
    splits: Splits,
    on_epoch: Callable[[str, int, float], None] | None = None,
) -> Fitted:
    """Phase 1, and for kinds with a spread phase 2 (with the transmission's quantiles), in
    place; the model is left in eval mode."""
    spec = model_kind(kind)
    history = History()
    started = time.perf_counter()
    train_mean(
        model,
        splits,
        config,
        history=history,
        on_epoch=None if on_epoch is None else (lambda e, t, v: on_epoch("mean", e, v)),
    )
    if kind == "ppann" and config.plan_fit:
        episodes = plan_episodes(dataset, splits.split)
        if episodes is not None:
            done = fit_plan_episodes(
                model,
                episodes,
                splits.train,
                splits.scale,
                lr=config.lr,
                epoch_windows=config.epoch_windows,
                batch_size=config.batch_size,
                seed=config.seed,
                on_epoch=None if on_epoch is None else (lambda e, loss: on_epoch("plan", e, loss)),
            )
            history.plan_fit = asdict(done)
    if spec.sigma_phase:
        stop = splits.split
        with torch.no_grad():
            model.transmission.copy_(
                torch.from_numpy(
                    fit_quantiles(
                        dataset.theta[:stop],
                        dataset.slider_position[:stop],
                        geometry=dataset.geometry,
                    )
                )
            )
        train_sigma(
            model,
            dataset,
            splits,
            config,
            history=history,
            on_epoch=None if on_epoch is None else (lambda e, loss: on_epoch("sigma", e, loss)),
            on_bounds=None if on_epoch is None else (lambda e, loss: on_epoch("bounds", e, loss)),
        )
    model.eval()
    return Fitted(kind, model, history, time.perf_counter() - started)
