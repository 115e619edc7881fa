"""The hidden layers' tanh, computed as 2 sigmoid(2x) - 1: the same function as `torch.tanh`
to within 4.5e-16, from a sigmoid that costs a quarter of torch's float64 tanh.

Why: torch's float64 `tanh` on the CPU (2.13.0, AVX-512, one thread) takes ~5 ns an element
where its `sigmoid` takes ~1.2, and the networks' tanh was the largest single cost of a
training: ~37 % of `crank run`'s two trainings (py-spy, session 70), the mean networks' 100
hidden units in phase 1 and the sigma networks' on every training sample in phase 2. With this
one a phase-1 step is ~1.25x and a phase-2 epoch 1.02-1.17x quicker (bench/bench_tanh.py), a
whole `crank run` 1.20x. Its
derivative is torch's own `tanh_backward`, 1 - y^2 from the output.

On the Intel Xeon kind (session 98, also AVX-512) torch's float64 tanh takes ~1.4 ns an element,
as its sigmoid does, and this tanh is the slower: 0.74-0.86x `nn.Tanh` in the same steps. It stays
the one formula on every machine all the same: a model's bits must not depend on the machine
that trained it (the reason training runs on one thread, ppann/fit.py).

The error: 2 sigmoid(2x) - 1 loses the relative precision of tanh near 0 (~1e-16 absolute
there, where tanh(x) ~ x), which a layer that sums its units into a linear output does not
see; at large |x| the sigmoid saturates to exactly 0 or 1, so the output is exactly -1 or 1,
as tanh's. tests/test_activation.py bounds it against torch.tanh and checks the gradient.
The numbers of a training are not torch.tanh's to the last bit: a model trained with it is
another draw of the same training, which is why the switch was checked on held-out machines
(bench/fast_tanh.md and bench/fast_tanh_5_9.md: training seeds 0-9, 4000 machines each;
bench/fast_tanh_lines.md: the wide lines; every issue-11 row met).
"""

from __future__ import annotations

import torch
from torch import nn


class _Tanh(torch.autograd.Function):
    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, x: torch.Tensor) -> torch.Tensor:
        # the same operations in the same order as torch.sigmoid(2 * x).mul_(2).sub_(1), so the
        # same bits, in one buffer instead of two: a second 3-23 MB tensor a layer cost ~5 % of
        # a phase-1 step and 3-23 % of a phase-2 epoch in isolation, not measurable in a whole
        # `crank run` (session 98, docs/benchmarks.md)
        y = x * 2
        torch.sigmoid(y, out=y)
        y.mul_(2).sub_(1)
        ctx.save_for_backward(y)
        return y

    @staticmethod
    def backward(ctx: torch.autograd.function.FunctionCtx, grad: torch.Tensor) -> torch.Tensor:
        (y,) = ctx.saved_tensors  # type: ignore[attr-defined]
        return torch.ops.aten.tanh_backward(grad, y)


def tanh(x: torch.Tensor) -> torch.Tensor:
    """tanh(x) as 2 sigmoid(2x) - 1, with tanh's derivative."""
    return _Tanh.apply(x)


class Tanh(nn.Module):
    """`nn.Tanh` computed by `tanh` above; no parameters, so checkpoints are unchanged."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return tanh(x)
