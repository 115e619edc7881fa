"""Benchmark: 2 × 100 open-loop replays against a bare mujoco.rollout; logging timed apart.

Prints, from the same run: wall time of playing the nominal and the robust torque open loop on
100 freshly drawn machines each (`crank replay`'s simulation path: per-run model copies, friction
written per machine, native batched rollout; logging excluded), wall time of bare
`mujoco.rollout` calls over the same model, runs, steps and threads (controls precomputed, one
shared model), and their ratio (target <= 1.5). Then, for information: the closed-loop replays
(one native call per 2 ms sample) and the MCAP campaign log of the 200 open-loop runs.

    python bench/bench_replay.py [--ocp logs/<run>/ocp.json] [--repeats 3]

Without --ocp the newest logs/*/ocp.json is used.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import mujoco
import numpy as np
from mujoco import rollout

from control.ocp_file import read_ocp
from replay.campaign import draw_machines, play
from replay.campaign_log import CampaignLog
from replay.config import ReplayConfig
from twin.physics import SliderCrank, load_model


def newest_ocp() -> Path:
    found = sorted(Path("logs").glob("*/ocp.json"), key=lambda p: p.stat().st_mtime)
    if not found:
        sys.exit("no logs/*/ocp.json: run `crank run` first or pass --ocp")
    return found[-1]


def bare(physics: SliderCrank, tau: dict[str, np.ndarray], runs: int, nthread: int) -> float:
    """Seconds for one rollout call per profile: `runs` runs of the shared model."""
    state0 = np.tile(physics.initial_state(np.pi, 0.0), (runs, 1))
    data = [mujoco.MjData(physics.model) for _ in range(nthread)]
    controls = {}
    for name, values in tau.items():
        c = np.zeros((runs, len(values), physics.model.nu))
        c[..., physics.layout.actuator["motor_torque"]] = values
        controls[name] = np.repeat(c, physics.substeps, axis=1)
    started = time.perf_counter()
    for c in controls.values():
        rollout.rollout(physics.model, data, state0, c)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ocp", type=Path, default=None)
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    ocp_path = args.ocp or newest_ocp()
    ocp = read_ocp(ocp_path)
    model, xml = load_model()
    physics = SliderCrank(model)
    config = ReplayConfig(runs=args.runs)
    machines = draw_machines(config, ocp.horizon)
    nthread = os.cpu_count() or 1
    tau = {p: ocp.profiles[p].tau for p in ocp.names}
    project, reference, closed, logging = [], [], [], []
    for _ in range(args.repeats):
        started = time.perf_counter()
        replays = [
            play(physics, ocp, profile=p, mode="open", machines=machines, config=config)
            for p in ocp.names
        ]
        project.append(time.perf_counter() - started)
        reference.append(bare(physics, tau, args.runs, nthread))
        started = time.perf_counter()
        for p in ocp.names:
            play(physics, ocp, profile=p, mode="closed", machines=machines, config=config)
        closed.append(time.perf_counter() - started)
        with tempfile.TemporaryDirectory() as tmp:
            started = time.perf_counter()
            with CampaignLog(
                Path(tmp) / "replay.mcap",
                header={"kind": "bench"},
                attachments={"model.xml": ("application/xml", xml.encode())},
                n_samples=ocp.horizon,
                ocp=ocp,  # with the Foxglove channels, as crank replay writes it
            ) as log:
                for replay in replays:
                    log.write_replay(replay, machines)
                log.finish()
            logging.append(time.perf_counter() - started)
    p, b, c, w = (statistics.median(x) for x in (project, reference, closed, logging))
    steps = 2 * args.runs * ocp.horizon * physics.substeps
    print(
        f"{ocp_path}: 2 × {args.runs} open-loop replays of {ocp.horizon} samples, "
        f"{steps:,} physics steps, {nthread} threads, median of {args.repeats}"
    )
    print(f"  crank replay simulation (open loop)  : {p:7.3f} s")
    print(f"  bare mujoco.rollout, same steps       : {b:7.3f} s")
    print(f"  ratio replay / bare                   : {p / b:7.3f}   (target <= 1.5)")
    print(f"  closed loop, 2 × {args.runs} runs (per-sample calls): {c:7.3f} s")
    print(f"  MCAP campaign log of the 2 × {args.runs} runs    : {w:7.3f} s")


if __name__ == "__main__":
    main()
