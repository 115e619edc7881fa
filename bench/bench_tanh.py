"""Benchmark: the networks' tanh (ppann/activation.py, 2 sigmoid(2x) - 1) against torch's
`nn.Tanh` in the PPANN's own work, on one thread (as a training runs): phase 1's step, the mean
networks' 10-step prediction of a batch of 4096 windows with the backward of its loss, and phase
2's step, the sigma networks on 288 000 samples (a 720 s dataset's training samples) with the
backward of a sum. The same model with each network's hidden layer swapped to `nn.Tanh` is the
reference; the two timed in turn (interleaved, each first every other time, so that the
host's drift falls on both): the median of each and of the pairs' ratios (how many times
quicker). The phase-2 figure moves from run to run (its tensors are 23 MB, allocated anew each
call): run it a few times.

    python bench/bench_tanh.py [--repeats 20]
"""

from __future__ import annotations

import argparse
import copy
import statistics
from collections.abc import Callable

import torch
from timing import median_seconds  # the script's folder is on the path
from torch import nn

from ppann.activation import Tanh
from ppann.model import PPANN, n_step_prediction


def with_torch_tanh(model: PPANN) -> PPANN:
    """A copy of `model` whose networks' hidden layers are torch's nn.Tanh."""
    reference = copy.deepcopy(model)
    for net in [*reference.mean_nets.values(), *reference.sigma_nets.values()]:
        assert isinstance(net[1], Tanh)
        net[1] = nn.Tanh()
    return reference


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(0)
    ours = PPANN()
    reference = with_torch_tanh(ours)
    x0 = torch.stack([6 * torch.rand(4096, generator=gen), 40 * torch.rand(4096, generator=gen)], 1)
    tau = 3 * torch.randn(4096, 10, generator=gen)
    theta = 60 * torch.rand(288_000, generator=gen, dtype=torch.float64)
    omega = 50 * torch.randn(288_000, generator=gen, dtype=torch.float64)
    x0, tau = x0.double(), tau.double()

    def phase1(model: PPANN) -> Callable[[], None]:
        return lambda: n_step_prediction(model, x0, tau).square().mean().backward()

    def phase2(model: PPANN) -> Callable[[], None]:
        return lambda: model.z_sigma(theta, omega).sum().backward()

    print(f"torch {torch.__version__}, {torch.backends.cpu.get_cpu_capability()}, one thread")
    for name, step in (
        ("phase 1 step (4096 windows x 10)", phase1),
        ("phase 2 epoch (288 000)", phase2),
    ):
        slow_step, fast_step = step(reference), step(ours)
        slow_step(), fast_step()  # warm-up
        slow: list[float] = []
        fast: list[float] = []
        for i in range(args.repeats):  # interleaved, each first in turn: drift falls on both
            pairs = [(slow_step, slow), (fast_step, fast)]
            for work, times in pairs if i % 2 == 0 else pairs[::-1]:
                times.append(1e3 * median_seconds(work, 1))
        ratio = statistics.median(s / f for s, f in zip(slow, fast, strict=True))
        print(
            f"{name:<34} nn.Tanh {statistics.median(slow):7.1f} ms, "
            f"ours {statistics.median(fast):7.1f} ms, ratio {ratio:4.2f}x (median of pairs)"
        )


if __name__ == "__main__":
    main()
