"""Robustness on tasks nobody tuned: one trained PPANN, several OCP tasks, each solved with five
Monte-Carlo seeds and every returned robust torque checked on held-out machines.

    python bench/bench_tasks.py --model logs/<run>/model.pt [--runs 1000] [--mc-seeds 0-4]
        [--mc-samples 1000] [--only "horizon 200"] [--profiles robust-fb,robust-pd]
        [--heldout-seed S] [--second-stage 9000] [--out tasks.json] [--tail-sampling plain|lines]
        [--drawn ROOT:I[,J...]]

Per task, Monte-Carlo seed and robust profile (default the open-loop `robust`; the tubes
`robust-fb`, `robust-pd` are checked closed loop under their own gains): the verdict (a robust
torque, or the one-line reason there is none), the margins and their standard errors, the cost
premium, and the held-out violation rate in the profile's loop with its exact 95 % bound; with
`--second-stage M` (session 94; 0 by default, as every run before it) a torque the first `--runs`
machines cannot judge is played on M more of the same draw and the row's rate, bound and verdict
are the staged check's over all of them (replay/heldout_stages.py), as `crank run` judges. A
task's verdict must not depend on the Monte-Carlo seed. Writes `tasks.json` beside the model
and prints a table. With `--drawn ROOT:I` the tasks are instead those bench/random_tasks.py
draws from ROOT, the I-th (0-based; several comma-separated), named as its sweep spec names them.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from random_tasks import draw_tasks, task_name  # the script's folder is on the path

from common.errors import ConfigError, CrankError
from control.config import TAIL_SAMPLINGS, OCPConfig, loops_of
from control.solve import solve_file
from crank.console import HELDOUT_SEED
from crank.study import parse_seeds
from replay.files import ocp_variability
from replay.heldout import heldout_file
from replay.rates import rate_upper, second_stage_end, second_stage_entry

TASKS: dict[str, dict] = {
    "paper (0.08 m at 50, 100; N 150)": {},
    "height 0.085": {"height": 0.085},
    "samples 60, 90": {"constraint_samples": (60, 90)},
    "horizon 200, samples 70, 130": {"horizon": 200, "constraint_samples": (70, 130)},
    "height 0.075, samples 40, 120": {"height": 0.075, "constraint_samples": (40, 120)},
}


def _none(reason: object) -> dict:
    """A row's verdict where the profile has no robust torque."""
    return {"verdict": "none", "error": str(reason)}


def drawn_tasks(text: str) -> dict[str, dict]:
    """--drawn ROOT:I[,J...]: bench/random_tasks.py's tasks I, J of ROOT, by its names."""
    try:
        root, indices = text.split(":")
        picked = sorted({int(i) for i in indices.split(",")})
        tasks = draw_tasks(int(root), picked[-1] + 1)
    except (ValueError, IndexError):
        raise SystemExit(f"bench_tasks: --drawn takes ROOT:I[,J...], got {text!r}") from None
    if picked[0] < 0:
        raise SystemExit(f"bench_tasks: --drawn indices must be >= 0, got {text!r}")
    named = {}
    for i in picked:
        task = tasks[i]
        named[task_name(i, task)] = task | {"constraint_samples": tuple(task["constraint_samples"])}
    return named


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True)
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--mc-seeds", default="0-4")
    parser.add_argument("--mc-samples", type=int, default=OCPConfig().mc_samples)
    parser.add_argument("--heldout-seed", type=int, default=HELDOUT_SEED)
    parser.add_argument(
        "--second-stage", type=int, default=0, help="machines of a second stage; 0: one look"
    )
    parser.add_argument("--only", default="", help="run the tasks whose name contains this")
    parser.add_argument("--out", default="tasks.json", help="file name beside the model")
    parser.add_argument("--profiles", default="robust", help="robust profiles, comma-separated")
    parser.add_argument(
        "--tail-sampling",
        default=OCPConfig().tail_sampling,
        choices=TAIL_SAMPLINGS,
        help="the own-tail check's draws",
    )
    parser.add_argument("--drawn", default="", help="bench/random_tasks.py's tasks: ROOT:I[,J]")
    args = parser.parse_args()
    tasks = drawn_tasks(args.drawn) if args.drawn else TASKS
    try:
        mc_seeds = parse_seeds(args.mc_seeds, option="--mc-seeds")
    except ConfigError as exc:
        raise SystemExit(f"bench_tasks: {exc}") from None
    if args.second_stage < 0:
        raise SystemExit(f"bench_tasks: --second-stage must be >= 0, got {args.second_stage}")
    profiles = tuple(p.strip() for p in args.profiles.split(","))
    model = Path(args.model)
    work = model.parent / "tasks"
    work.mkdir(exist_ok=True)
    rows = []
    for t, (task, options) in enumerate(tasks.items()):
        if args.only not in task:
            continue
        for mc_seed in mc_seeds:
            config = OCPConfig(
                **options,
                mc_seed=mc_seed,
                mc_samples=args.mc_samples,
                profiles=profiles,
                fallback=(),  # the verdicts of the profiles asked for, as before session 54
                tail_sampling=args.tail_sampling,
            )
            ocp_path = work / f"task{t}-mc{mc_seed}.json"
            started = time.perf_counter()
            try:
                solved = solve_file(model, ocp_path, config=config)
            except CrankError as exc:
                for name in profiles:
                    rows.append({"task": task, "mc_seed": mc_seed, "profile": name} | _none(exc))
                print(f"{task:<34} mc {mc_seed}: no robust torque: {exc}", flush=True)
                continue
            loops = {name: solved[name]["loop"] for name in profiles if name in solved}
            heldout = heldout_file(
                ocp_path,
                work / f"task{t}-mc{mc_seed}.heldout.json",
                model=model,
                runs=args.runs,
                seed=args.heldout_seed,
                variability=ocp_variability(ocp_path),
                modes=loops_of(loops),
                extend_to=second_stage_end(args.runs, args.second_stage),
            )
            for name in profiles:
                row = {"task": task, "mc_seed": mc_seed, "profile": name}
                if name not in solved:
                    reason = solved["refused"][name]
                    rows.append(row | _none(reason))
                    print(f"{task:<34} mc {mc_seed} {name}: none: {reason}", flush=True)
                    continue
                loop = loops[name]
                held = heldout["profiles"][name][loop]
                nominal_cost = solved["nominal"]["cost"]
                row |= {
                    "verdict": "robust",
                    "loop": loop,
                    "margins_mm": [1e3 * (h - config.height) for h in solved[name]["heights"]],
                    "tightening_se_mm": [1e3 * v for v in solved[name]["tightening_se"]],
                    "premium": solved[name]["cost"] / nominal_cost - 1,
                    "heldout_rate": held["rate"],
                    "heldout_upper_95": held["rate_upper_95"],
                    "heldout_runs": args.runs,
                    "heldout_verdict": heldout["verdicts"][name],
                    "nominal_heldout_rate": heldout["profiles"]["nominal"][loop]["rate"],
                    "seconds": time.perf_counter() - started,
                }
                staged = second_stage_entry(heldout, name)
                if staged is not None:  # the row of all the machines played
                    below, runs = staged["counts"][-1], staged["machines"][-1]
                    row |= {
                        "heldout_first_below": staged["counts"][0],
                        "heldout_runs": runs,
                        "heldout_rate": below / runs,
                        "heldout_upper_95": rate_upper(below, runs),
                    }
                rows.append(row)
                print(
                    f"{task:<34} mc {mc_seed} {name}: margins "
                    + ", ".join(f"{m:.2f}" for m in row["margins_mm"])
                    + f" mm, premium {100 * row['premium']:.1f} %, held-out {loop} "
                    f"{100 * row['heldout_rate']:.2f} % (bound "
                    f"{100 * row['heldout_upper_95']:.2f} %) of {row['heldout_runs']}: "
                    f"{row['heldout_verdict']}, nominal "
                    f"{100 * row['nominal_heldout_rate']:.1f} %",
                    flush=True,
                )
    for task in (t for t in tasks if args.only in t):
        for name in profiles:
            verdicts = {r["verdict"] for r in rows if r["task"] == task and r["profile"] == name}
            print(
                f"{task}, {name}: verdict {'/'.join(sorted(verdicts))} over the Monte-Carlo seeds"
            )
    out = model.parent / args.out  # beside the model, unless absolute
    out.parent.mkdir(parents=True, exist_ok=True)
    record = {"runs": args.runs, "heldout_seed": args.heldout_seed, "profiles": list(profiles)}
    out.write_text(json.dumps(record | {"rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
