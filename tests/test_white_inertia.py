"""How the Monte-Carlo draws z_J's white noise (PPANNConfig.white_inertia): eq. 14's quotient
or its first order about the mean, on both rollout paths, and the option's way through the
training config and the checkpoint."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from ppann import fit
from ppann.checkpoint import load, save
from ppann.heads import FusedHeads
from ppann.model import PPANN, constant_ppann
from ppann.model_config import ModelConfigError, PPANNConfig
from ppann.montecarlo import rollout
from ppann.train_config import TrainConfig, TrainConfigError
from twin.dataset import Dataset

ROOT = Path(__file__).resolve().parents[1]
MEAN, SIGMA = (-0.3, 0.2, -0.5), (0.14, 0.05, 0.04)
"""z_J's rho = sigma / (1 + mu) = 0.2, about a trained model's over top dead centre."""


def _heads(form: str) -> FusedHeads:
    return FusedHeads(constant_ppann(z_mean=MEAN, z_sigma=SIGMA, config=_config(form)))


def _config(form: str) -> PPANNConfig:
    return PPANNConfig(white_inertia=form)


@pytest.mark.parametrize("compiled", [True, False])
def test_one_step_is_eq_14_with_z_drawn_or_its_first_order_in_z_j(compiled: bool) -> None:
    """One step from (theta, omega) under tau with given normals, written out from the prior's
    J, B, K: the quotient divides by J (1 + mu_J + sigma_J eps_J); the linear form is the
    acceleration at mu_J times 1 - sigma_J eps_J / (1 + mu_J); z_B and z_K are drawn alike."""
    x0, tau, n = np.array([2.0, 3.0]), np.array([0.7]), 512
    eps = np.random.default_rng(5).standard_normal((1, n, 3))
    physical = PPANNConfig()
    j, b, k = physical.j_m, physical.b_m, physical.k_m
    mu, sigma = np.array(MEAN), np.array(SIGMA)
    z = mu + sigma * eps[0]
    drive = tau[0] - b * (1 + z[:, 1]) * x0[1] - k * (1 + z[:, 2]) * x0[0]
    expected = {
        "quotient": drive / (j * (1 + z[:, 0])),
        "linear": drive / (j * (1 + mu[0])) * (1 - sigma[0] * eps[0][:, 0] / (1 + mu[0])),
    }
    for form, alpha in expected.items():
        heads = _heads(form)
        # one step: a per-trajectory draw is the same numbers as a per-step one
        states = rollout(heads, x0, tau, n_samples=n, eps=eps, compiled=compiled)
        got = (states[:, 1, 1] - x0[1]) / heads.dt
        np.testing.assert_allclose(got, alpha, rtol=2e-5 if compiled else 1e-12)


def test_the_linear_draw_keeps_the_mean_models_acceleration_and_the_quotient_does_not() -> None:
    """Over 200 000 draws the linear form's average acceleration is the mean model's within
    three standard errors; the quotient's is above it by E[1 / (1 + rho eps)] - 1 = rho^2 +
    3 rho^4 + ... (4.5 % at rho = 0.2, the rest of the series 0.06 %), its spread wider."""
    x0, tau, n = np.array([2.0, 3.0]), np.array([0.7]), 200_000
    eps = np.random.default_rng(6).standard_normal((1, n, 3))
    eps[..., 1:] = 0.0  # z_J's draw alone
    rho = SIGMA[0] / (1 + MEAN[0])
    got = {}
    for form in ("quotient", "linear"):
        heads = _heads(form)
        states = rollout(heads, x0, tau, n_samples=n, eps=eps, compiled=False)
        got[form] = (states[:, 1, 1] - x0[1]) / heads.dt
    mean_model = rollout(heads, x0, tau, n_samples=2, compiled=False)  # no draws: the mean
    mean_alpha = (mean_model[0, 1, 1] - x0[1]) / heads.dt
    se = got["linear"].std() / math.sqrt(n)
    assert abs(got["linear"].mean() - mean_alpha) < 3 * se
    assert got["linear"].std() == pytest.approx(abs(mean_alpha) * rho, rel=0.01)
    excess = got["quotient"].mean() / mean_alpha - 1
    assert excess == pytest.approx(rho**2 + 3 * rho**4, abs=0.003)
    assert got["quotient"].std() > 1.1 * got["linear"].std()


def test_the_option_reaches_the_model_and_the_checkpoint(tmp_path: Path) -> None:
    """[train] white_inertia builds the PPANN with it ("linear" by default); a checkpoint keeps
    it, and one written before the option (no key) reads as eq. 14's quotient; unknown forms
    are refused."""
    data = Dataset(*(np.zeros(4) for _ in range(6)))
    model = fit.new_model(data, kind="ppann", config=TrainConfig())  # the default since s. 55
    assert isinstance(model, PPANN) and model.config.white_inertia == "linear"
    paper = TrainConfig(white_inertia="quotient")
    assert fit.new_model(data, kind="ppann", config=paper).config.white_inertia == "quotient"
    save(tmp_path / "m.pt", model, kind="ppann", extra={"history": {}})
    assert load(tmp_path / "m.pt")[0].config.white_inertia == "linear"
    payload = torch.load(tmp_path / "m.pt", weights_only=True)
    del payload["config"]["white_inertia"]
    torch.save(payload, tmp_path / "old.pt")
    assert load(tmp_path / "old.pt")[0].config.white_inertia == "quotient"
    with pytest.raises(ModelConfigError, match="white_inertia must be one of"):
        replace(PPANNConfig(), white_inertia="exact")
    with pytest.raises(TrainConfigError, match="white_inertia must be one of"):
        TrainConfig(white_inertia="")


def test_the_bench_script_sets_the_form_and_keeps_the_weights(tmp_path: Path) -> None:
    """bench/white_inertia.py: the same weights and payload, the form changed."""
    model = constant_ppann(z_mean=MEAN, z_sigma=SIGMA)
    save(tmp_path / "m.pt", model, kind="ppann", extra={"history": {"epochs": 3}})
    script = ROOT / "bench" / "white_inertia.py"
    out = tmp_path / "linear.pt"
    args = [sys.executable, str(script), "--model", str(tmp_path / "m.pt"), "--out", str(out)]
    subprocess.run(args, check=True, capture_output=True, cwd=ROOT)
    before, after = load(tmp_path / "m.pt"), load(out)
    assert (before[0].config.white_inertia, after[0].config.white_inertia) == ("quotient", "linear")
    assert after[1]["history"] == {"epochs": 3}
    for name, tensor in before[1]["state_dict"].items():
        assert torch.equal(tensor, after[1]["state_dict"][name])
