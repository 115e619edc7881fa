"""report.md's held-out part, and the words and numbers the run's summaries share with it: each
robust profile's verdict on the held-out machines, the machines below, and the calibration
tables (predicted / observed σ of the slider and of θ per Monte-Carlo mode)."""

from __future__ import annotations

from typing import Any

from control.config import law_of, loop_of
from replay.placement import in_words, named

LOOP_WORDS = {
    "open": "open loop",
    "closed": "closed loop under its LQR gains",
    "mpc": "under the online MPC",
}


def loop_words(loop: str, profile: str) -> str:
    """A loop a profile was played in, in words: closed is under the profile's own gains (its
    LQR, or robust-pd's fixed PD)."""
    if loop == "closed" and law_of(profile) == "pd":
        return "closed loop under its fixed PD"
    return LOOP_WORDS[loop]


def number(value: Any, spec: str) -> str:
    """`value` formatted by `spec`, or n/a where there is none."""
    return "n/a" if value is None else format(value, spec)


DIVERGED_RATIO = 1e3
"""A predicted / observed ratio beyond this is a Monte-Carlo whose draws ran away (the
`trajectory` mode's white σ held for a whole run), not a calibration."""


def diverged(ratio: float | None) -> bool:
    """No ratio to read: a run-away Monte-Carlo's (beyond DIVERGED_RATIO, or not finite), or
    none was left."""
    return ratio is None or not abs(ratio) <= DIVERGED_RATIO


def ratio_text(value: Any) -> str:
    """A predicted/observed ratio; one beyond DIVERGED_RATIO is shown as such, not as 70
    digits (n/a where none was left)."""
    if value is not None and abs(value) > DIVERGED_RATIO:
        return f"diverged ({value:.1e})"
    return number(value, ".2f")


def own_rate(entry: dict[str, Any]) -> str:
    """What the model's own Monte-Carlo put below the height (heldout.json version 4)."""
    if "model_rate" not in entry:
        return ""
    own = entry["model_rate"]
    return (
        f" (the model's own Monte-Carlo of {own['draws']} trajectories: {100 * own['rate']:.2f} %)"
    )


def verdict_words(
    entry: dict[str, Any], heldout: dict[str, Any], *, profile: str | None = None
) -> str:
    """A profile's held-out verdict in a sentence's words (replay/rates.py); `profile`'s in
    its own loop judged on all its machines where the check had a second stage for it."""
    from replay.rates import machines_to_confirm, second_stage_entry, verdict

    staged = second_stage_entry(heldout, profile)
    if staged is not None:
        (first, total), (n1, n2) = staged["counts"], staged["machines"]
        word = {"holds": "**holds**", "fails": "**does not hold**"}
        return (
            f"{word.get(staged['verdict'], '**is not confirmed**')} on all {n2} machines "
            f"played: {total} below ({100 * total / n2:.2f} %; the first {n1} had {first}, too "
            f"few machines to decide, so it was played on {n2 - n1} more of the same draw, "
            f"judged by a staged design whose risk of a wrong verdict of holding is "
            f"{100 * heldout['staged']['error']:.1f} %)."
        )
    target = heldout["target_rate"]
    said = verdict(entry["violating_runs"], heldout["runs"], target=target)
    if said == "fails":
        return "**does not hold**."
    if said == "holds":
        return "**holds**."
    return (
        f"**is not confirmed**: within it on these {heldout['runs']} machines, but they are too "
        f"few for the bound to be (none below on {machines_to_confirm(target)} would confirm it)."
    )


def heldout_lines(heldout: dict[str, Any] | None) -> list[str]:
    """The held-out verdicts and the calibration table of report.md (nothing if not run)."""
    if heldout is None:
        return []
    profiles = heldout["profiles"]
    lines = [
        "## Held-out machines",
        "",
        f"On {heldout['runs']} held-out machines (root seed {heldout['seed']}, streams no other "
        f"stage draws from):",
        "",
    ]
    for name in list(profiles)[1:]:
        for loop in heldout["modes"]:
            robust, nominal = profiles[name][loop], profiles["nominal"][loop]
            pd = loop == "closed" and heldout.get("feedback") == "pd"
            sized = loop_of(name) == loop and name in heldout.get("holds", {})
            word = verdict_words(robust, heldout, profile=name if sized else None)
            own = " (the loop it was tightened for)" if sized else ""
            words = "closed loop under the fixed PD" if pd else loop_words(loop, name)
            lines.append(
                f"- {words}{own}, the {name} torque left the slider below the height "
                f"on {100 * robust['rate']:.2f} % of machines (exact 95 % upper bound "
                f"{100 * robust['rate_upper_95']:.2f} %){own_rate(robust)}, the nominal one "
                f"on {100 * nominal['rate']:.1f} %. Against the target of <= "
                f"{100 * heldout['target_rate']:.1f} % the {name} torque {word}"
            )
            lines += [f"  - machine {i} below: {in_words(where)}" for i, where in named(robust)]
    allow = (
        "these machines and that Monte-Carlo allow (a bootstrap over the machines, widened by "
        "the Monte-Carlo's standard error)"
        if heldout.get("version", 0) >= 6
        else "these machines allow (a bootstrap over them)"
    )
    lines += [
        "",
        "Predicted / observed σ of the slider under the OCP's own torque, per Monte-Carlo mode "
        f"({heldout['mc_samples']} trajectories); in brackets the 95 % interval {allow}:",
        "",
    ]
    first = next(iter(next(iter(profiles.values())).values()))
    modes = list(next(iter(first["samples"].values()))["predicted"])
    lines.append(
        "| profile | loop | sample | observed σ mm | lowest mm | skew | " + " | ".join(modes) + " |"
    )
    lines.append("|" + "---|" * (6 + len(modes)))
    for profile, played in profiles.items():
        for loop, entry in played.items():
            for sample, e in entry["samples"].items():
                ratios = [with_interval(e["predicted"][m]) for m in modes]
                observed = f"{1e3 * e['observed_sigma']:.2f}"
                if "observed_sigma_ci95" in e:
                    low, high = (1e3 * v for v in e["observed_sigma_ci95"])
                    observed += f" ({low:.2f}–{high:.2f})"
                lines.append(
                    f"| {profile} | {loop} | {sample} | {observed} | "
                    f"{1e3 * e['lowest']:.1f} | {e['skew']:+.2f} | " + " | ".join(ratios) + " |"
                )
    if "theta" not in next(iter(first["samples"].values())):
        return [*lines, ""]  # a heldout.json of version 2
    lines += [
        "",
        "The same for the crank angle θ (near top dead centre the slider's σ magnifies an error "
        "in θ's):",
        "",
        "| profile | loop | sample | observed θ σ mrad | " + " | ".join(modes) + " |",
        "|" + "---|" * (4 + len(modes)),
    ]
    for profile, played in profiles.items():
        for loop, entry in played.items():
            thetas = [(k, e["theta"]) for k, e in entry["samples"].items()]
            for sample, e in [*thetas, ("last", entry["theta_final"])]:
                ratios = [ratio_text(e["predicted"][m]["ratio"]) for m in modes]
                lines.append(
                    f"| {profile} | {loop} | {sample} | {1e3 * e['observed_sigma']:.1f} | "
                    + " | ".join(ratios)
                    + " |"
                )
    return [*lines, ""]


def with_interval(predicted: dict[str, Any]) -> str:
    """A calibration ratio, with its interval where heldout.json has one."""
    text = ratio_text(predicted["ratio"])
    if predicted.get("ratio_ci95") and not diverged(predicted["ratio"]):
        low, high = predicted["ratio_ci95"]
        text += f" ({low:.2f}–{high:.2f})"
    return text
