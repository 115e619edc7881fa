"""ppann/activation.py: tanh as 2 sigmoid(2x) - 1 against torch.tanh, its gradient, and the
networks that use it."""

from __future__ import annotations

import math

import torch
from torch import nn

from ppann.activation import Tanh, tanh
from ppann.baselines import BlackBox
from ppann.model import PPANN


def test_values_match_torch_tanh() -> None:
    x = torch.cat(
        [
            torch.linspace(-30.0, 30.0, 200_001, dtype=torch.float64),
            torch.logspace(-300, 2, 1001, dtype=torch.float64),
            -torch.logspace(-300, 2, 1001, dtype=torch.float64),
            torch.tensor([0.0, -0.0, 400.0, -400.0, 1e300, -1e300], dtype=torch.float64),
        ]
    )
    error = (tanh(x) - torch.tanh(x)).abs()
    assert float(error.max()) <= 4.5e-16
    # saturated: exactly +-1 where tanh is, and never past it
    assert float(tanh(torch.tensor(40.0, dtype=torch.float64))) == 1.0
    assert float(tanh(torch.tensor(-40.0, dtype=torch.float64))) == -1.0
    assert float(tanh(x).abs().max()) == 1.0
    ends = tanh(torch.tensor([math.inf, -math.inf, math.nan], dtype=torch.float64))
    assert ends[0] == 1.0 and ends[1] == -1.0 and torch.isnan(ends[2])


def test_gradient_is_one_minus_square() -> None:
    x = torch.linspace(-6.0, 6.0, 1201, dtype=torch.float64, requires_grad=True)
    y = tanh(x)
    (grad,) = torch.autograd.grad(y.sum(), x)
    assert torch.allclose(grad, 1 - torch.tanh(x.detach()) ** 2, rtol=0, atol=1e-15)
    generator = torch.Generator().manual_seed(0)
    small = torch.randn(20, 3, dtype=torch.float64, generator=generator, requires_grad=True)
    assert torch.autograd.gradcheck(tanh, (small,))


def test_float32_and_no_grad() -> None:
    x = torch.linspace(-5.0, 5.0, 1001)
    with torch.no_grad():
        y = Tanh()(x)
    assert y.dtype == torch.float32
    assert float((y - torch.tanh(x)).abs().max()) <= 2.4e-7


def test_networks_use_it() -> None:
    """Every hidden layer of the PPANN's six networks and of the black box is this tanh, and a
    network's output is its Linear-tanh-Linear by hand (control/dynamics.py writes the same
    layers with CasADi's tanh)."""
    model = PPANN()
    nets = [*model.mean_nets.values(), *model.sigma_nets.values()]
    assert len(nets) == 6
    for net in nets:
        assert isinstance(net[1], Tanh) and not isinstance(net[1], nn.Tanh)
        x = torch.randn(50, net[0].in_features, dtype=torch.float64)
        by_hand = torch.tanh(x @ net[0].weight.T + net[0].bias) @ net[2].weight.T + net[2].bias
        with torch.no_grad():
            assert torch.allclose(net(x), by_hand, rtol=0, atol=1e-14)
    box = BlackBox()
    assert any(isinstance(m, Tanh) for m in box.modules())
    assert not any(isinstance(m, nn.Tanh) for m in box.modules())


def test_forward_is_the_plain_formula_to_the_bit() -> None:
    """The forward's one buffer computes what torch.sigmoid(2 * x).mul_(2).sub_(1) computes, bit
    for bit (a model trained before session 98 is the model trained now), in float64 and float32,
    on a layer-sized batch and on views that are not contiguous, leaving its input as it was;
    the gradient is tanh_backward of that output."""
    generator = torch.Generator().manual_seed(0)
    for dtype in (torch.float64, torch.float32):
        x = (8 * torch.randn(4096, 100, generator=generator, dtype=torch.float64)).to(dtype)
        for view in (x, x.t(), x[::3, 1::2]):
            before = view.clone()
            plain = torch.sigmoid(2 * view).mul_(2).sub_(1)
            assert torch.equal(tanh(view), plain)
            assert torch.equal(view, before)
    data = torch.randn(64, 100, generator=generator, dtype=torch.float64)
    x = data.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(tanh(x).sum(), x)
    y = torch.sigmoid(2 * data).mul_(2).sub_(1)
    assert torch.equal(grad, torch.ops.aten.tanh_backward(torch.ones_like(y), y))
