"""Would a δ drawn with the trajectory's own load close the tubes' tail at sample 50? The model's
own rate under a closed-loop profile (replay/model_rate.py: its Monte-Carlo in the OCP's mode,
20 000 trajectories, under the profile's gains) with δ, the crank's angle to the motor, drawn as
the product draws it (one draw from the model's marginal per trajectory) and drawn from the
dataset's samples whose torque through the gap, now and LAG samples before, fell in the same
cell as the trajectory's (bench/sample50_parts.md: on the twin δ moves with the motor angle at
sample 50, which a marginal draw cannot; bench/transmission_load.md: that load explains most of
δ). A diagnosis beside the product, nothing in it changes.

The load u = τ − J α − b ω − f sign ω along each trajectory (τ the torque its law applied, α from
its ω) and on the dataset (α from the measured ω), J, b, f fitted on the dataset alone
(transmission_load.py's grid search); δ on the dataset from the measured slider
(ppann/transmission.py), its cells CELLS × CELLS equal-count bins of u now and u before. A
trajectory's δ is a dataset sample drawn at random from its cell (cells with fewer than LEAST
samples: the marginal).

    python bench/load_delta.py --ocp OCP.json --model MODEL.pt --data DATASET.mcap [PLAN.mcap]
        [--profiles robust-fb,robust-pd] [--draws 20000]
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np
from transmission_load import CELLS, LEAST, Conditioned, load, samples, torque_through_gap

from common import streams
from control.ocp_file import read_ocp
from ppann.checkpoint import load as load_checkpoint
from ppann.heads import FusedHeads
from ppann.montecarlo import Feedback, monte_carlo
from ppann.transmission import draw
from twin.physics import SAMPLE_RATE

LAG = 5
"""Samples (10 ms) between the two loads (bench/transmission_load.md: the lag explaining most)."""


def fitted_coefficients(parts: dict[str, np.ndarray]) -> tuple[float, float, float]:
    """J, b, f minimising δ's spread within 20 bins of u (transmission_load.py's grid)."""
    delta = parts["delta"]
    grid = itertools.product(
        np.linspace(0.0, 2e-3, 11), np.linspace(0.0, 0.16, 9), np.linspace(0.0, 0.06, 5)
    )

    def left(c: tuple) -> float:
        u = (load(parts, c),)
        return Conditioned.fit(delta, u, 20).left(delta, u)

    return tuple(float(v) for v in min(grid, key=left))  # type: ignore[return-value]


class CellDraw:
    """δ drawn from the dataset's samples of a cell of (u now, u before)."""

    def __init__(self, delta: np.ndarray, now: np.ndarray, before: np.ndarray) -> None:
        self.edges = tuple(np.quantile(u, np.linspace(0, 1, CELLS + 1)) for u in (now, before))
        cell = self._cell(now, before)
        order = np.argsort(cell, kind="stable")
        self.delta = delta[order]
        self.start = np.searchsorted(cell[order], np.arange(CELLS * CELLS))
        self.count = np.bincount(cell, minlength=CELLS * CELLS)

    def _cell(self, now: np.ndarray, before: np.ndarray) -> np.ndarray:
        bins = [
            np.clip(np.searchsorted(e, u, side="right") - 1, 0, CELLS - 1)
            for e, u in zip(self.edges, (now, before), strict=True)
        ]
        return bins[0] * CELLS + bins[1]

    def __call__(
        self, now: np.ndarray, before: np.ndarray, fallback: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        cell = self._cell(now, before)
        count = self.count[cell]
        pick = self.start[cell] + np.floor(rng.uniform(size=cell.size) * count).astype(int)
        usable = count >= LEAST
        out = fallback.copy()
        out[usable] = self.delta[pick[usable]]
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", type=Path, required=True)
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--data", type=Path, nargs="+", required=True)
    parser.add_argument("--profiles", default="robust-fb,robust-pd")
    parser.add_argument("--draws", type=int, default=20000)
    args = parser.parse_args()
    parts_of = [samples(path, (LAG,), truth=False) for path in args.data]
    parts = {k: np.concatenate([p[k] for p in parts_of]) for k in parts_of[0]}
    coefficients = fitted_coefficients(parts)
    cells = CellDraw(parts["delta"], load(parts, coefficients), load(parts, coefficients, LAG))
    print(
        f"dataset {', '.join(map(str, args.data))}: {parts['delta'].size} samples; fitted J "
        f"{coefficients[0]:.1e}, b {coefficients[1]:.3f}, f {coefficients[2]:.3f}; cells "
        f"{CELLS} x {CELLS}, {int(np.sum(cells.count >= LEAST))} with at least {LEAST} samples"
    )
    model, _ = load_checkpoint(args.model)
    heads = FusedHeads(model)
    ocp = read_ocp(args.ocp)
    c = ocp.config
    index = np.array(c.constraint_samples) - 1
    for name in args.profiles.split(","):
        planned = ocp.profiles[name]
        states = np.stack([planned.theta, planned.omega], axis=-1)
        gains = np.stack([planned.gain_theta, planned.gain_omega], axis=-1)
        law = Feedback(states, gains, c.torque_limit)
        bands = monte_carlo(
            heads,
            states[0],
            np.asarray(planned.tau)[: index.max() + 1],  # the load at the last sample too
            n_samples=args.draws,
            mode=c.mc_mode,
            seed=streams.stream(c.mc_seed, "monte_carlo"),
            feedback=law,
        )
        x = bands.samples  # (draws, index.max() + 1, 2)
        steps = x.shape[1] - 1
        error = x[:, :steps] - states[None, :steps]
        applied = np.clip(
            planned.tau[None, :steps] - np.einsum("nkj,kj->nk", error, gains[:steps]),
            -c.torque_limit,
            c.torque_limit,
        )
        omega = x[:, :, 1]
        alpha = np.gradient(omega, 1.0 / SAMPLE_RATE, axis=1)[:, :steps]
        u = torque_through_gap(applied, alpha, omega[:, :steps], coefficients)
        marginal = draw(
            heads.transmission,
            (args.draws,),
            np.random.default_rng(streams.stream(c.mc_seed, "transmission")),
        )
        rng = np.random.default_rng(7)
        print(f"{name} ({c.mc_mode}, {args.draws} trajectories, closed loop under its gains):")
        any_marginal = np.zeros(args.draws, bool)
        any_loaded = np.zeros(args.draws, bool)
        for k, i in zip(c.constraint_samples, index, strict=True):
            theta = x[:, i, 0]
            loaded = cells(u[:, i], u[:, i - LAG], marginal, rng)
            for what, delta, seen in (
                ("marginal (the product's)", marginal, any_marginal),
                ("drawn with its load", loaded, any_loaded),
            ):
                slider = heads.geometry.slider_position(theta + delta)
                below = slider < c.height
                seen |= below
                print(
                    f"  sample {k:3d}, δ {what:24s}: δ mean {1e3 * delta.mean():+6.2f} sd "
                    f"{1e3 * delta.std():5.2f} mrad, "
                    f"corr(θ, δ) {np.corrcoef(theta, delta)[0, 1]:+.2f}, slider mean "
                    f"{1e3 * slider.mean():.3f} sd {1e3 * slider.std():.3f} mm, below "
                    f"{100 * below.mean():.3f} %"
                )
        print(
            f"  the model's own rate: {100 * any_marginal.mean():.3f} % with the marginal, "
            f"{100 * any_loaded.mean():.3f} % with δ drawn with its load"
        )


if __name__ == "__main__":
    main()
