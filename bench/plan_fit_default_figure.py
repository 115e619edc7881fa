"""docs/plan_fit_seeds.png: the paper task's robust torque on training seeds 0-9 of the shipped
default since session 96 (`plan_fit`; bench/plan_fit_default.csv, root 20261283) beside the
trapezoid default without it (sessions 88-89, roots 20261260-1): held-out machines below with the
exact 95 % bound, the cost premium, predicted / observed σ of the slider at samples 50 and 100.

    python bench/plan_fit_default_figure.py --out docs/plan_fit_seeds.png
"""

from __future__ import annotations

import argparse

from trapezoid_rows_figure import BENCH, draw, from_csv, trapezoid_rows  # the script's folder


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    args = parser.parse_args()
    lanes = [
        ("trapezoid, sessions 88-89 (roots 20261260-1)", "tab:blue", trapezoid_rows()),
        (
            "plan_fit, session 96 (root 20261283)",
            "tab:orange",
            from_csv(BENCH / "plan_fit_default.csv"),
        ),
    ]
    draw(
        lanes,
        title="The paper task's robust torque, 4000 held-out machines per seed:\n"
        "the shipped default (plan_fit) beside the trapezoid without it "
        "(bench/plan_fit_default.md)",
        out=args.out,
    )


if __name__ == "__main__":
    main()
