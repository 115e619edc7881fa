"""The own-tail check's estimate against its cost, plain trajectories and line sampling
(issue 11, session 46; development, no machines): for a default model's k-3 robust torques of
the paper task (the check off, so the torque is the loop's), the rate with two standard errors
at fixed draws of each kind against the seconds it took, beside the 0.5 % target.

    python bench/tail_lines_figure.py --model <model.pt> [--mc-seeds 1,3]
        [--out docs/tail_lines.png]
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from control.config import TARGET_RATE, OCPConfig
from control.ocp import NominalOCP
from control.profiles import decide
from control.tail import tail_check
from ppann.checkpoint import load
from ppann.heads import FusedHeads

PLAIN = (5_000, 20_000, 80_000, 320_000)
LINES = (250, 1000, 4000, 16_000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--mc-seeds", default="1,3")
    parser.add_argument("--out", default="docs/tail_lines.png")
    args = parser.parse_args()
    model, _ = load(args.model)
    heads = FusedHeads(model)
    seeds = [int(s) for s in args.mc_seeds.split(",")]
    fig, axes = plt.subplots(1, len(seeds), figsize=(5.5 * len(seeds), 4.2), squeeze=False)
    for ax, seed in zip(axes[0], seeds, strict=True):
        config = OCPConfig(mc_seed=seed, tail_check=False)
        ocp = NominalOCP(model, config)
        result = decide(model, config, profile="robust", ocp=ocp, nominal=ocp.solve(), heads=heads)
        arguments = {
            "tightening": result.tightening,
            "population": result.robust_uncertainty.population,
        }
        tail_check(heads, result.robust, config, draws=PLAIN[0], **arguments)  # warm
        for kind, counts, colour in (("plain", PLAIN, "tab:gray"), ("lines", LINES, "tab:blue")):
            checked = replace(config, tail_sampling=kind)
            points = [
                tail_check(heads, result.robust, checked, draws=n, **arguments) for n in counts
            ]
            for n, c in zip(counts, points, strict=True):
                print(
                    f"mc {seed} {kind} {n}: {100 * c.rate:.3f} % ± {100 * c.standard_error:.3f} "
                    f"in {c.wall_time:.3f} s"
                )
            ax.errorbar(
                [c.wall_time for c in points],
                [100 * c.rate for c in points],
                yerr=[200 * c.standard_error for c in points],
                fmt="o-",
                color=colour,
                capsize=3,
                label=f"{kind}: {', '.join(f'{n:,}' for n in counts)}",
            )
        ax.axhline(100 * TARGET_RATE, color="tab:red", lw=1, ls="--", label="target 0.5 %")
        ax.set_xscale("log")
        ax.set_xlabel("wall time of the check [s]")
        ax.set_ylabel("own rate below the height [%] (± 2 standard errors)")
        ax.set_title(f"k-3 torque, Monte-Carlo seed {seed}")
        ax.legend(fontsize=8, loc="best")
    fig.suptitle("The own-tail check: plain trajectories against line sampling (one model)")
    fig.tight_layout()
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
