"""Figure of `bench/tail_parts.py` outputs at one constraint sample: the crank angle's skew on the
twin and in the model per part, the slider's σ ratio before and after the model's Monte-Carlo is
moved back by its lead, and the share below the height on the twin (with its exact 95 %
interval) against the model's, before and after the move.

    python bench/tail_parts_figure.py --out docs/tail_parts.png [--sample 130] \
        LABEL=tail.json [LABEL=...]
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from labelled import figure_parser, labelled_json  # the script's folder is on the path
from scipy import stats as scistats

from common.figures import save_figure
from ppann.figures import CALIBRATION_BAND
from replay.rates import rate_upper

PARTS = ("line", "white", "machines")


def interval(below: int, n: int) -> tuple[float, float]:
    """The exact (Clopper–Pearson) 95 % interval of a rate of `below` in `n`."""
    low = scistats.beta.ppf(0.025, below, n - below + 1) if below else 0.0
    return float(low), rate_upper(below, n, confidence=0.975)


def main() -> None:
    parser = figure_parser(__doc__, inputs="tail.json")
    parser.add_argument("--sample", help="the constraint sample (default: the last)")
    args = parser.parse_args()
    runs = []
    for label, name, data in labelled_json(args.runs, script="tail_parts_figure"):
        samples = data["samples"]
        k = args.sample or max((s for s in samples if s.isdigit()), key=int)
        if k not in samples:
            raise SystemExit(f"tail_parts_figure: {name} has no constraint sample {k}")
        runs.append((label, samples[k]))
    fig, (skew, ratio, rate) = plt.subplots(1, 3, figsize=(16, 5.2))
    x = range(len(runs))
    for p, part in enumerate(PARTS):
        offset = (p - 1) * 0.22
        twin = [f[part]["twin_theta"]["skew"] for _, f in runs]
        model = [f[part]["model_theta"]["skew"] for _, f in runs]
        skew.plot([i + offset for i in x], twin, "o", mfc="none", color=f"C{p}")
        skew.plot([i + offset for i in x], model, "o", color=f"C{p}", label=part)
        for i in x:
            skew.plot([i + offset] * 2, [twin[i], model[i]], color=f"C{p}", lw=0.8)
    skew.axhline(0.0, color="black", lw=0.8)
    skew.set_ylabel("skew of θ (open: twin, filled: model)")
    skew.set_title(f"the crank angle's skew at sample {k}, per part")
    low = min(
        min(f[p]["model_theta"]["skew"], f[p]["twin_theta"]["skew"]) for _, f in runs for p in PARTS
    )
    skew.set_ylim(bottom=low - 0.25)  # room for the legend below the points
    skew.legend(fontsize=8, loc="lower left", ncol=3)
    for i, (_, f) in enumerate(runs):
        line = f["line"]
        observed = line["twin"]["sigma"]
        ratio.plot(i - 0.08, line["model"]["sigma"] / observed, "s", color="C0")
        ratio.plot(i + 0.08, line["model_moved"]["sigma"] / observed, "^", color="C3")
        n, below = line["twin"]["n"], line["twin"]["below"]
        low, high = interval(below, n)
        rate.errorbar(
            i - 0.12,
            100 * below / n,
            yerr=[[100 * (below / n - low)], [100 * (high - below / n)]],
            fmt="o",
            color="black",
            capsize=3,
        )
        rate.plot(i, 100 * line["model"]["rate"], "s", color="C0")
        rate.plot(i + 0.12, 100 * line["model_moved"]["rate"], "^", color="C3")
    ratio.axhspan(*CALIBRATION_BAND, color="green", alpha=0.08)
    ratio.axhline(1.0, color="black", lw=0.8)
    ratio.set_ylabel("slider σ, model / twin (line)")
    ratio.set_title("■ the model's Monte-Carlo, ▲ moved back by its lead")
    rate.axhline(0.5, color="grey", ls="--", lw=0.8)
    rate.set_ylabel("share below the height, % (line)")
    rate.set_title("● twin (95 % interval), ■ model, ▲ model moved back")
    for ax in (skew, ratio, rate):
        ax.set_xticks(list(x), [label for label, _ in runs], rotation=45, ha="right", fontsize=8)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, args.out)


if __name__ == "__main__":
    main()
