"""A lab's data: few machines, each run several times. Does it matter that training knows which
episodes are one machine's (twin.dataset.episode_machines, session 78)?

    python bench/runs_per_machine.py --seeds 0,1,2 --machines 8 --runs 9 \
        --heldout-seed 20261243 --out logs/runs_per_machine [--variability line-15]

Per training seed: `crank generate --episodes-per-machine RUNS` (MACHINES x RUNS episodes of 10 s,
the machines drawn from --variability; the held-out machines are drawn from the same scenario,
the one ocp.json carries),
and a copy of the same samples with the machine ids taken out of its run record (what training
read before session 78: every episode a machine of its own). Each is trained (`train_and_report`,
the PPANN alone, the two side by side on one core each), solved (`crank solve`, its default
profiles) and checked on held-out machines (`crank heldout --runs 1000 --seed S`). Prints per seed
and reading: the machines phase 2 counted, the fitted machine σ (J, B, K) with its likelihood
bound at the line's confidence, the line mean's standard error, each robust profile's final
margins and cost premium (or its refusal) and its held-out machines below the height with the
exact 95 % bound. Writes `runs_per_machine.json` and `.md` in --out.

About 12 minutes a seed on 2 idle cores (the two trainings dominate).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from twin.mcap_dataset import read_dataset, read_model_xml, read_truth, write_dataset

READINGS = ("grouped", "episodes")


def ungrouped(path: Path, out: Path) -> None:
    """The dataset at `path` with no machine ids: every episode read as a machine of its own."""
    data, truth = read_dataset(path), read_truth(path)
    run = dict(data.run)
    run["episodes"] = [{k: v for k, v in e.items() if k != "machine_id"} for e in run["episodes"]]
    run["machine_ids_removed"] = "bench/runs_per_machine.py: each episode read as its own machine"
    write_dataset(out, data, truth, run=run, model_xml=read_model_xml(path))


def crank(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "crank", *args])


def wait(*procs: subprocess.Popen) -> None:
    codes = [p.wait() for p in procs]
    if any(codes):
        raise SystemExit(f"a crank command failed: exit codes {codes}")


def train(data: Path, out: Path, seed: int, threads: int) -> subprocess.Popen:
    code = (
        f"import torch; torch.set_num_threads({threads})\n"
        "from ppann.pipeline import train_and_report\n"
        "from ppann.train_config import TrainConfig\n"
        f"train_and_report({str(data)!r}, {str(out)!r}, config=TrainConfig(seed={seed}), "
        "baselines=False, figures=False)\n"
    )
    return subprocess.Popen([sys.executable, "-c", code])


def summary(folder: Path) -> dict:
    report = json.loads((folder / "model.report.json").read_text())
    ppann = report["models"]["ppann"]
    ocp_path = folder / "ocp.json"
    out = {
        "spread_data": ppann["spread_data"],
        "machine_sigma": ppann["machine_sigma"],
        "machine_sigma_upper": ppann["machine_sigma_upper"],
        "line_mean_se": ppann["line_mean_se"],
        "line_mean_quantile": ppann.get("line_mean_quantile"),  # since session 79
        "epochs": ppann["epochs"],
    }
    if not ocp_path.exists():
        out["ocp"] = json.loads((folder / "ocp.failed.json").read_text())["error"]
        return out
    ocp = json.loads(ocp_path.read_text())
    nominal = ocp["nominal"]["cost"]
    height = ocp["config"]["height"]
    out["profiles"] = {}
    for name in ocp["profiles"][1:]:
        if name in ocp.get("refused", {}):
            out["profiles"][name] = {"refused": ocp["refused"][name]}
            continue
        r = ocp[name]
        out["profiles"][name] = {
            "premium": r["cost"] / nominal - 1,
            "margins_mm": [1e3 * (h - height) for h in r["heights"]],
            "population_mm": [1e3 * v for v in r.get("population", [])],
        }
    out["refused"] = ocp.get("refused", {})
    held = json.loads((folder / "heldout.json").read_text())
    out["verdicts"] = held["verdicts"]
    out["heldout"] = {
        profile: {
            mode: {
                "below": v["violating_runs"],
                "rate_upper_95": v["rate_upper_95"],
                "sigma_ratio": {
                    k: x["predicted"].get("mixed", {}).get("ratio") for k, x in v["samples"].items()
                },
            }
            for mode, v in modes.items()
        }
        for profile, modes in held["profiles"].items()
    }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--machines", type=int, default=8)
    parser.add_argument("--runs", type=int, default=9)
    parser.add_argument("--heldout-seed", type=int, required=True)
    parser.add_argument("--heldout-runs", type=int, default=1000)
    parser.add_argument("--variability", default="paper", help="scenario or range file")
    parser.add_argument("--out", type=Path, default=Path("logs/runs_per_machine"))
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    args.out.mkdir(parents=True, exist_ok=True)
    record = {"argv": sys.argv, "config": {k: str(v) for k, v in vars(args).items()}, "seeds": {}}
    for seed in seeds:
        started = time.perf_counter()
        root = args.out / f"seed-{seed}"
        folders = {name: root / name for name in READINGS}
        for folder in folders.values():
            folder.mkdir(parents=True, exist_ok=True)
        data = folders["grouped"] / "dataset.mcap"
        if not data.exists():
            wait(crank("generate", "--seed", str(seed), "--episodes-per-machine",
                       str(args.runs), "--seconds", str(10.0 * args.machines * args.runs),
                       "--variability", args.variability,
                       "--no-figures", "--out", str(data)))  # fmt: skip
        flat = folders["episodes"] / "dataset.mcap"
        if not flat.exists():
            ungrouped(data, flat)
        jobs = [
            train(folder / "dataset.mcap", folder / "model.pt", seed, threads=1)
            for folder in folders.values()
            if not (folder / "model.pt").exists()
        ]
        wait(*jobs)
        for folder in folders.values():
            if not (folder / "ocp.json").exists() and not (folder / "ocp.failed.json").exists():
                p = crank("solve", "--model", str(folder / "model.pt"),
                          "--out", str(folder / "ocp.json"))  # fmt: skip
                p.wait()  # a refusal of every profile exits non-zero: ocp.failed.json says why
            if (folder / "ocp.json").exists() and not (folder / "heldout.json").exists():
                wait(crank("heldout", "--ocp", str(folder / "ocp.json"),
                           "--model", str(folder / "model.pt"),
                           "--runs", str(args.heldout_runs), "--seed", str(args.heldout_seed),
                           "--out", str(folder / "heldout.json")))  # fmt: skip
        record["seeds"][seed] = {name: summary(f) for name, f in folders.items()}
        record["seeds"][seed]["seconds"] = time.perf_counter() - started
        (args.out / "runs_per_machine.json").write_text(json.dumps(record, indent=1))
        print(json.dumps(record["seeds"][seed], indent=1)[:4000], flush=True)


if __name__ == "__main__":
    main()
