"""Figure of `bench/plan_lead.py` outputs: the plan's lead over the twin's nominal machine along
each torque (the robust profile and the nominal one of the same ocp.json), and at each
constraint sample the σ ratios of θ and of the slider, and the slider's with the Monte-Carlo
moved back to the machines' mean θ, against the calibration's 0.8–1.25.

    python bench/plan_lead_figure.py --out docs/plan_lead.png LABEL=lead.json [LABEL=...]

The leads along the torques are computed again here (the twin's nominal machine without the
white force, no held-out machine: plan_lead.py's `nominal_runs`); the ratios are read.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from heldout_options import line_of
from labelled import figure_parser, labelled_json  # the script's folder is on the path
from matplotlib.lines import Line2D
from plan_lead import nominal_runs

from common.figures import save_figure
from control.ocp_file import read_ocp
from ppann.figures import CALIBRATION_BAND
from twin import MODEL_PATH
from twin.physics import SliderCrank, load_model


def main() -> None:
    parser = figure_parser(__doc__, inputs="lead.json")
    args = parser.parse_args()
    runs = [(label, data) for label, _, data in labelled_json(args.runs, script="plan_lead_figure")]
    physics = SliderCrank(load_model(MODEL_PATH)[0])
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 5), width_ratios=(1.4, 1))
    samples: list[str] = []
    for m, (label, data) in enumerate(runs):
        path = data["settings"]["ocp"]
        ocp = read_ocp(path)
        x0 = physics.initial_state(ocp.config.theta_start, ocp.config.omega_start)
        line = line_of(path, data["settings"]["variability"])  # the line plan_lead ran on
        for name, style in (("robust", "-"), ("nominal", ":")):
            profile = ocp.profiles[name]
            twin = nominal_runs(physics, line, profile, x0)["theta"].mean(axis=0)
            lead = 1e3 * (profile.theta - twin)
            left.plot(
                np.arange(1, len(lead) + 1),
                lead,
                style,
                color=f"C{m}",
                label=f"{label} {name}",
            )
        samples = list(data["samples"])
        for j, k in enumerate(samples):
            f = data["samples"][k]
            x = j + (m - (len(runs) - 1) / 2) * 0.12
            right.plot(x - 0.03, f["theta_ratio"], "o", color=f"C{m}", mfc="none")
            right.plot(x, f["ratio"], "s", color=f"C{m}")
            right.plot(x + 0.03, f["ratio_at_twin_mean"], "^", color=f"C{m}")
    for k in samples:
        left.axvline(int(k), color="grey", lw=0.8)
    left.axhline(0.0, color="black", lw=0.8)
    left.set_xlabel("sample (2 ms); grey: the constraint samples")
    left.set_ylabel("plan θ − twin's nominal machine θ, mrad")
    left.set_title("the mean model's lead along the torque (solid robust, dotted nominal)")
    left.legend(fontsize=7, ncol=2)
    right.axhspan(*CALIBRATION_BAND, color="green", alpha=0.08)
    for bound in CALIBRATION_BAND:
        right.axhline(bound, color="green", lw=0.8)
    right.set_xticks(range(len(samples)), [f"sample {k}" for k in samples])
    right.set_ylabel("predicted / observed σ (mixed), held-out machines")
    right.set_title("the calibration's σ ratios, and the slider's without the lead")
    marks = [
        Line2D([], [], marker="o", mfc="none", color="black", ls="", label="θ"),
        Line2D([], [], marker="s", color="black", ls="", label="slider"),
        Line2D(
            [],
            [],
            marker="^",
            color="black",
            ls="",
            label="slider, Monte-Carlo moved\nto the machines' mean θ",
        ),
    ]
    seeds = [Line2D([], [], color=f"C{m}", label=label) for m, (label, _) in enumerate(runs)]
    right.legend(handles=marks + seeds, fontsize=7, loc="lower left")
    right.set_xlim(-0.6, len(samples) - 0.4)
    fig.tight_layout()
    save_figure(fig, args.out)


if __name__ == "__main__":
    main()
