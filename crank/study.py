"""`crank study`: the chain once per seed, each checked on held-out machines, into one table.

A robustness claim needs several training seeds and a held-out check on many machines (1000 by
default, drawn from the held-out streams with a root seed of their own). For each seed the study
runs `run_chain` into `<out>/seed-<s>/` and reads one row back from its files; a seed whose chain
fails (for example no robust profile exists) is a row with its one-line error, and the study goes
on. A study run again with `resume=True` keeps every seed folder that has its report.md and
redoes the rest.

Files in `<out>/`: `study.json` (config and rows), `study.csv`, `study.md` (the table and the
verdict against the targets), `study.png` (crank/study_figure.py: violation rates, premium and
calibration against seed).
"""

from __future__ import annotations

import csv
import io
import json
import re
import shutil
import time
from collections import Counter
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any

from common.atomic import atomic_path, writes
from common.errors import ConfigError, CrankError
from common.figures import save_figure
from common.jsonio import write_json
from control.config import loop_of
from control.robust import BeyondStrokeError
from crank.chain import Hooks, RunConfig, run_chain
from crank.estimate import Span, run_time
from crank.study_figure import figure
from replay.rates import TARGET_RATE as TARGET_HELDOUT_RATE
from replay.rates import rate_upper, second_stage_entry, verdict

MAX_SEEDS = 1000


def parse_seeds(text: str, *, option: str = "--seeds") -> tuple[int, ...]:
    """'0-9', '0,3,7' or '2' → seeds; anything else is a ConfigError naming the text and the
    `option` it was given to."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        match = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not match:
            raise ConfigError(f"{option} takes a range like 0-9 or a list like 0,3,7; got {text!r}")
        low = int(match.group(1))
        high = int(match.group(2)) if match.group(2) else low
        if high < low:
            raise ConfigError(f"{option} range {part!r} runs backwards")
        seeds.extend(range(low, high + 1))
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"{option} repeats a seed: {text!r}")
    if not 1 <= len(seeds) <= MAX_SEEDS:
        raise ConfigError(f"{option} must name 1..{MAX_SEEDS} seeds, got {len(seeds)}")
    return tuple(seeds)


def seed_rows(seed: int, run_dir: Path) -> list[dict[str, Any]]:
    """The study's rows of a finished seed folder, one per robust profile."""
    return [{"seed": seed} | row for row in run_rows(run_dir, run_dir / "ocp.json")]


def run_rows(leaf: Path, ocp_path: Path) -> list[dict[str, Any]]:
    """The figures of a finished chain, one row per robust profile it asked for (a refused one:
    its reason as the row's error) and per fallback it solved (`fallback` true): its report.json
    and replay stats in `leaf`, and the ocp.json it played (a sweep keeps them in separate step
    folders)."""
    report = json.loads((leaf / "report.json").read_text())
    stats = json.loads((leaf / report["replay"]["stats"]).read_text())
    ocp = json.loads(ocp_path.read_text())
    rows = []
    fallback = ocp.get("fallback", [])
    for name in [*ocp["config"]["profiles"], *fallback]:
        if name in ocp.get("refused", {}):
            spread = ocp.get("refused_spread", {}).get(name, {})  # as run_study's failed seed
            rows.append(
                {"profile": name, "error": ocp["refused"][name]}
                | {f"refused_{k}": v for k, v in spread.items() if k != "se"}
            )
        else:
            rows.append(_profile_row(name, report, stats, ocp) | {"fallback": name in fallback})
    return rows


def _profile_row(
    name: str, report: dict[str, Any], stats: dict[str, Any], ocp: dict[str, Any]
) -> dict[str, Any]:
    """One robust profile's figures, in the loop it was tightened for."""
    heldout = report["heldout"]
    mode = ocp["config"]["mc_mode"]
    k = ocp["config"]["k_sigma"]
    loop = loop_of(name)
    played = {p: stats["profiles"][p][loop] for p in ("nominal", name)}
    ppann = report["ppann"]["models"]["ppann"]
    row: dict[str, Any] = {
        "profile": name,
        "error": None,
        "loop": loop,
        "robust_100": played[name]["violating_runs"],  # of campaign_runs (100 by default)
        "nominal_100": played["nominal"]["violating_runs"],
        "campaign_runs": played[name]["runs"],
        "premium": stats["ocp"]["premiums"][name],
        "robust_lowest_mm": 1e3 * min(c["lowest"] for c in played[name]["constraint"].values()),
        "phase1_epochs": ppann["epochs"],
        "phase1_converged": ppann["phase1_converged"],
        "machine_sigma": ppann["machine_sigma"],
        "mc_mode": mode,
        # what the torque was solved with: its own tail's check may have raised k or sent it
        # to the quantile tightening (control/tail.py; keys absent before sessions 30, 31)
        "solved_tightening": ocp[name].get("tightening_method", ocp["config"]["tightening"]),
        "solved_k": ocp[name].get("k_sigma", k),
        "wall_s": report["wall_seconds"]["total"],
    }
    row["solved_with"] = f"{row['solved_tightening']} k {row['solved_k']:g}"
    if report.get("plan_round") is not None:  # its first torque is only played, never returned
        row["first_round_tail_refused"] = bool(report["plan_round"].get("first_tail_refused"))
    if heldout is not None and loop in heldout["modes"]:
        robust, nominal = heldout["profiles"][name][loop], heldout["profiles"]["nominal"][loop]
        row |= {
            "heldout_runs": heldout["runs"],
            "robust_heldout_rate": robust["rate"],
            "robust_heldout_upper_95": robust["rate_upper_95"],
            "robust_heldout_verdict": heldout.get("verdicts", {}).get(name)
            or verdict(robust["violating_runs"], heldout["runs"], target=heldout["target_rate"]),
            "nominal_heldout_rate": nominal["rate"],
            "robust_heldout_lowest_mm": 1e3 * min(s["lowest"] for s in robust["samples"].values()),
            # by index in the held-out draw: the same root gives every seed the same machines
            "robust_heldout_machines": robust.get("violating_machines"),
        } | _second_stage(heldout, name, robust)
        if "model_rate" in robust:  # heldout.json version 4
            row["robust_model_rate"] = robust["model_rate"]["rate"]
        for sample, entry in robust["samples"].items():
            predicted = entry["predicted"][mode]
            row[f"pred_{k:g}sigma_{sample}_mm"] = 1e3 * k * predicted["sigma"]
            row[f"obs_{k:g}sigma_{sample}_mm"] = 1e3 * k * entry["observed_sigma"]
            row[f"ratio_{sample}"] = predicted["ratio"]
            if predicted.get("ratio_ci95"):  # heldout.json version 5
                row[f"ratio_{sample}_low"], row[f"ratio_{sample}_high"] = predicted["ratio_ci95"]
            if "theta" in entry:  # heldout.json version 3
                row[f"theta_ratio_{sample}"] = entry["theta"]["predicted"][mode]["ratio"]
    return row


def _second_stage(heldout: dict[str, Any], name: str, first: dict[str, Any]) -> dict[str, Any]:
    """A row's held-out figures over every machine its torque was played on where the check
    went to a second stage for profile `name` (replay/rates.py `second_stage_entry`; `first`:
    its first-stage entry in its loop): the rate, its
    one-look 95 % bound and the machines below of all of them, and the first stage's count
    beside; none where it did not (the first stage's figures are the row's already). The lowest
    slider position, the calibration and the nominal's rate stay the first stage's: the second
    stage plays the robust torque only and keeps its counts."""
    staged = second_stage_entry(heldout, name)
    if staged is None:
        return {}
    below, machines = staged["counts"][-1], staged["machines"][-1]
    listed = first.get("violating_machines")
    more = staged["violating_machines"]
    return {
        "heldout_runs": machines,
        "heldout_first_runs": staged["machines"][0],
        "robust_heldout_first_below": staged["counts"][0],
        "robust_heldout_rate": below / machines,
        "robust_heldout_upper_95": rate_upper(below, machines),
        "robust_heldout_machines": None if listed is None or more is None else listed + more,
    }


def confirmed(row: dict[str, Any]) -> bool:
    """Whether a row's held-out check confirms its torque within the target: its verdict (the
    staged one where the check had a second stage), or for a row without one its 95 % bound."""
    if "robust_heldout_verdict" in row:
        return row["robust_heldout_verdict"] == "holds"
    return row["robust_heldout_upper_95"] <= TARGET_HELDOUT_RATE


@writes("out", all_or_nothing=False)
def run_study(
    base: RunConfig,
    seeds: tuple[int, ...],
    out: str | Path,
    *,
    resume: bool = False,
    progress: Callable[[int], AbstractContextManager[Hooks]] | None = None,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    on_estimate: Callable[[dict[str, Span], int], None] | None = None,
) -> dict[str, Any]:
    """Run the chain per seed into `out`/seed-<s>/ and write the study files; return study.json.

    `on_estimate` gets one run's estimated time per stage and the number of seeds left to run,
    once the inputs are checked; `progress(seed)`, a block around each seed's chain, gives the
    chain's hooks."""
    out = Path(out)
    if out.exists() and not resume:
        raise ConfigError(f"study folder already exists: {out} (use --resume to continue it)")
    for seed in seeds:  # a resumed study's finished seeds ran with these settings, or none runs
        check_same_settings(out / f"seed-{seed}", base.with_seed(seed))
    left = [s for s in seeds if not (out / f"seed-{s}" / "report.md").is_file()]
    estimate = run_time(base)
    if on_estimate:
        on_estimate(estimate, len(left))
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    started = time.perf_counter()
    for seed in seeds:
        run_dir = out / f"seed-{seed}"
        if not (run_dir / "report.md").is_file():
            shutil.rmtree(run_dir, ignore_errors=True)  # an unfinished seed starts over
            try:
                with progress(seed) if progress else nullcontext(None) as hooks:
                    run_chain(base.with_seed(seed), run_dir, hooks=hooks, argv=[])
            except CrankError as exc:
                row = {"seed": seed, "profile": "/".join(base.ocp.profiles), "error": str(exc)}
                if isinstance(exc, BeyondStrokeError):  # the figures of "no open-loop profile"
                    row |= {
                        "refused_sample": exc.sample,
                        "refused_tightening": exc.tightening,
                        "refused_available": exc.available,
                        "refused_line": exc.line,
                    }
                run_dir.mkdir(parents=True, exist_ok=True)
                (run_dir / "error.txt").write_text(str(exc) + "\n")
                rows.append(row)
                if on_row:
                    on_row(row)
                continue
        for row in seed_rows(seed, run_dir):
            rows.append(row)
            if on_row:
                on_row(row)
    study = {
        "format": "crank-study",
        "version": 1,
        "seeds": list(seeds),
        "config": base.as_dict(),
        "target_heldout_rate": TARGET_HELDOUT_RATE,
        "estimated_seconds": (estimate["total"] * len(seeds)).as_list(),
        "rows": rows,
        "wall_s": time.perf_counter() - started,
    }
    write_json(out / "study.json", study, indent=2)
    write_csv(out / "study.csv", rows)
    (out / "study.md").write_text(markdown(study))
    save_figure(figure(rows), out / "study.png")
    return study


def check_same_settings(run_dir: Path, asked: RunConfig) -> None:
    """A finished run folder of a study being resumed must have run with the settings `asked`
    (but for `figures`, which changes no number), or the study would mix two configurations
    under one heading.

    Raises:
      ConfigError: naming the first setting that differs, with both values.
    """
    if not (run_dir / "report.md").is_file():
        return  # not finished: run again from the start with `asked`
    from crank.resume import resumed_config

    theirs, ours = _flat(resumed_config(run_dir).as_dict()), _flat(asked.as_dict())
    differ = [k for k in (*ours, *theirs) if k != "figures" and theirs.get(k) != ours.get(k)]
    if not differ:
        return
    key = next((k for k in differ if k.endswith(".name")), differ[0])  # a scenario by its name
    raise ConfigError(
        f"{run_dir} ran with {key} = {theirs.get(key)!r}, this study asks {ours.get(key)!r}: "
        "resume the study with the options it was started with, or start a new study folder"
    )


def _flat(values: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts as one dict of dotted keys."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        if isinstance(value, dict):
            out |= _flat(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """`rows` as CSV with every key any row has (tables left out), written atomically."""
    keys: list[str] = []
    for row in rows:
        keys += [k for k in row if k not in keys and not isinstance(row[k], dict)]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=keys, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    with atomic_path(path) as tmp:
        tmp.write_text(buffer.getvalue())


def _cell(value: Any, spec: str = "") -> str:
    if value is None:
        return "n/a"
    if isinstance(value, float):
        return format(value, spec or ".3g")
    return str(value)


def markdown(study: dict[str, Any]) -> str:
    """study.md: verdict against the targets first, then one row per seed."""
    rows = study["rows"]
    ok = [r for r in rows if r.get("error") is None]
    lines = [f"# Seed study: seeds {', '.join(str(s) for s in study['seeds'])}", ""]
    runs = study["config"]["replay"]["runs"]  # campaign machines per profile and loop
    scenario = study["config"]["generation"]["variability"]["name"]
    lines.append(
        f"Variability scenario `{scenario}`, Monte-Carlo `{study['config']['ocp']['mc_mode']}` "
        f"({study['config']['ocp']['mc_samples']} samples, {study['config']['ocp']['tightening']} "
        f"tightening, confidence {study['config']['ocp'].get('confidence', 0):g}; each seed's "
        f'torque as "solved with" says), held-out seed {study["config"]["heldout_seed"]}.'
    )
    lines.append("")
    for name in study["config"]["ocp"]["profiles"]:
        mine = [r for r in rows if name in str(r.get("profile")).split("/")]
        good = [r for r in mine if r.get("error") is None and "robust_heldout_rate" in r]
        if not good:
            continue
        loop = loop_of(name)
        worst = max(r["robust_heldout_rate"] for r in good)
        holds = all(r["robust_heldout_rate"] <= study["target_heldout_rate"] for r in good)
        campaign = all(r["robust_100"] == 0 for r in good)
        every = len(good) == len(mine)
        lines.append(
            f"- {name} {loop} loop on held-out machines: worst seed {100 * worst:.2f} % "
            f"(target <= {100 * study['target_heldout_rate']:.1f} %): "
            f"**{'met' if holds and every else 'NOT met'}**"
        )
        unsure = [r for r in good if not confirmed(r)]
        if unsure:
            lines.append(
                f"  - on {len(unsure)} seed(s) the held-out verdict does not confirm it (worst "
                f"95 % bound {100 * max(r['robust_heldout_upper_95'] for r in unsure):.2f} %): "
                "too few held-out machines to decide"
            )
        lines.append(
            f"- {name} {loop} loop 0/{runs} campaign runs on every seed: "
            f"**{'yes' if campaign and every else 'no'}**"
        )
        lines += _recurring(good)
    if not study["config"].get("heldout_runs", 1):
        lines.append("- no held-out check (--heldout-runs 0): no rate to judge")
    failed = [r for r in rows if r.get("error")]
    if failed:
        lines.append(f"- {len(failed)} seed(s) gave no result (errors below)")
    lines += ["", "![violation rate and premium against seed](study.png)", ""]
    columns = [
        ("seed", "seed", ""),
        ("profile", "profile", ""),
        ("robust_100", f"robust /{runs}", ""),
        ("nominal_100", f"nominal /{runs}", ""),
        ("robust_heldout_rate", "robust held-out", ".2%"),
        ("robust_heldout_upper_95", "95 % bound", ".2%"),
        ("nominal_heldout_rate", "nominal held-out", ".1%"),
        ("premium", "premium", ".1%"),
        ("solved_with", "solved with", ""),
        ("robust_heldout_lowest_mm", "lowest held-out mm", ".1f"),
        ("phase1_epochs", "phase-1 epochs", ""),
    ]
    ratio_keys = sorted({k for r in ok for k in r if k.startswith("ratio_")})
    bound = {"low": " 95 % from", "high": " 95 % to"}  # the held-out set's interval
    columns += [
        (k, f"pred/obs σ @{k.split('_')[1]}{bound.get(k.split('_')[-1], '')}", ".2f")
        for k in sorted(ratio_keys, key=lambda k: k.replace("_low", "_a").replace("_high", "_b"))
    ]
    theta_keys = sorted({k for r in ok for k in r if k.startswith("theta_ratio_")})
    columns += [(k, f"θ pred/obs @{k.split('_')[2]}", ".2f") for k in theta_keys]
    lines.append("| " + " | ".join(c[1] for c in columns) + " |")
    lines.append("|" + "---|" * len(columns))
    for r in rows:
        if r.get("error"):
            lines.append(f"| {r['seed']} | {r.get('profile', '')} | error: {r['error']} |")
            continue
        lines.append("| " + " | ".join(_cell(r.get(key), spec) for key, _, spec in columns) + " |")
    return "\n".join(lines) + "\n"


def _recurring(rows: list[dict[str, Any]]) -> list[str]:
    """A line naming the held-out machines below the height under more than one seed's torque
    (every seed plays the same held-out machines), or none: the seeds' counts then share
    machines of the line's tail and are not independent samples of it."""
    listed = [r["robust_heldout_machines"] for r in rows if r.get("robust_heldout_machines")]
    counts = Counter(m for machines in listed for m in set(machines))
    again = sorted((m for m, n in counts.items() if n > 1), key=lambda m: (-counts[m], m))
    if not again:
        return []
    named = ", ".join(f"{m} ({counts[m]} of {len(rows)} seeds)" for m in again)
    return [
        f"  - the same held-out machines below under several seeds' torques: {named}; the "
        "seeds' counts are not independent (each seed's heldout.json places them in the line)"
    ]
