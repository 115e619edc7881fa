"""Every subcommand against bad input, as one table: each case must end with exit code 2, a
single `error: ...` line on stderr naming what was wrong, no traceback, nothing on stdout's
success path, and no new file or folder, neither in the working folder nor beside the inputs
(whose bytes stay as they were).

The commands run in this process (`crank.cli.main` with its argv), so the table costs
milliseconds a case instead of an interpreter start; tests/test_cli.py and tests/test_outputs.py
run the CLI as a subprocess where the process itself matters (kills, locks, a full disk)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from crank.cli import main
from tests.checkpoints import constant_checkpoint
from tests.rig_runs import import_runs, play_runs
from twin import MODEL_PATH
from twin.dataset import GenerationConfig
from twin.generation import generate_file
from twin.physics import SliderCrank
from twin.rig_import import ImportSpec, import_table

RANGES = {
    "swapped": "[motor_damping]\nlow = 0.1\nhigh = 0.05\n",
    "nan": "[slider_damping]\nlow = nan\nhigh = 9\n",
    "unknown": "[motor_wobble]\nlow = 0.1\nhigh = 0.2\n",
    "negative": "[motor_damping]\nlow = -0.1\nhigh = 0.2\n",
    "broken": "[motor_damping\nlow = ",
    "drift_text": 'drift = "no"\n',
    "cfg_unknown": "[ocp]\nheigth = 0.08\n",
    "cfg_old": '[ocp]\nfeedback = "lqr"\n',
    "cfg_stop": '[train]\nearly_stopping = "best"\n',
    "cfg_terms": '[train]\nmachine_terms = "whole"\n',
    "cfg_plan": "[plan]\ndither = nan\n",
    "cfg_plan_many": "[plan]\nepisodes = 20000\n",
    "cfg_type": "[ocp]\nhorizon = 'x'\n",
    "cfg_range": "[ocp]\nhorizon = 2\n",
    "cfg_pd": '[ocp]\nprofiles = ["robust-pd"]\npd_kp = 30.0\n',
    "cfg_scheme": '[ocp]\nmargin_scheme = "fast"\n',
    "cfg_no_samples": "[ocp]\nconstraint_samples = []\n",
    "sw_ok": "[grid]\nseed = [0, 1]\n",
    "sw_unknown": '[grid]\n"ocp.heigth" = [0.08]\n',
    "sw_base_unknown": "[base]\nseeds = 3\n[grid]\nseed = [0]\n",
    "sw_section": "[grids]\nseed = [0, 1]\n",
    "sw_empty": "[base]\nseed = 1\n",
    "sw_axis": "[grid]\nseed = []\n",
    "sw_scalar": "[grid]\nseed = 3\n",
    "sw_range": '[grid]\n"ocp.horizon" = [150, 2]\n',
    "sw_seed": "[grid]\nseed = [-1, 0]\n",
    "sw_type": '[grid]\n"ocp.height" = ["high"]\n',
    "sw_same": '[grid]\nseed = [0]\n[[cases]]\nname = "a"\n[[cases]]\nname = "b"\n',
    "sw_names": '[[cases]]\nname = "a"\n[[cases]]\nname = "a"\nseed = 1\n',
    "sw_cases": "cases = [1, 2]\n",
    "sw_big": '[grid]\nseed = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]\n"ocp.height" = ['
    + ", ".join(str(0.07 + i * 1e-5) for i in range(1001))
    + "]\n",
}


def _rig_csv(t: np.ndarray) -> str:
    return "time,enc,cmd\n" + "".join(f"{x:.17g},{np.sin(x):.17g},0.5\n" for x in t)


_T = np.arange(0, 0.1, 1e-3)
RIG = "t=time,theta=enc,tau=cmd"
RIG_TABLES = {
    "rig": _rig_csv(_T),
    "gap": _rig_csv(np.r_[_T, 0.2 + _T]),
    "nan": _rig_csv(_T).replace(",0.5\n", ",nan\n", 7),
    "back": _rig_csv(np.r_[_T[:50], _T[49:]]),
    "word": _rig_csv(_T).replace(",0.5\n", ",half\n", 3),
    "jitter": _rig_csv(np.cumsum(np.where(np.arange(100) % 2, 1e-3, 2e-3))),
    "few": _rig_csv(_T[:2]),
}
"""Rig tables for crank import: a good one, and each with one fault."""


@pytest.fixture(scope="module")
def inputs(
    tmp_path_factory: pytest.TempPathFactory, ocp_path: Path, physics: SliderCrank
) -> dict[str, Path]:
    """Valid inputs of every stage and broken ones, in a folder of their own."""
    d = tmp_path_factory.mktemp("inputs")
    ds = d / "ds.mcap"
    generate_file(GenerationConfig(seconds=2.0, episode_seconds=1.0), out=ds, figures=False)
    model = d / "m.pt"
    constant_checkpoint(model)
    ocp = d / "ocp.json"
    ocp.write_bytes(ocp_path.read_bytes())
    (d / "text.txt").write_text("not a file of any of ours\n")
    (d / "text.mcap").write_text("not an mcap\n")
    (d / "empty.mcap").write_bytes(b"")
    (d / "text.pt").write_text("not a checkpoint\n")
    (d / "cut.pt").write_bytes(model.read_bytes()[: model.stat().st_size // 2])
    (d / "text.json").write_text("{not json")
    (d / "list.json").write_text("[1, 2]")
    (d / "other.json").write_text(json.dumps({"format": "something-else", "version": 1}))
    (d / "garbage.xml").write_text("<mujoco><worldbody><body><joint type='x'/>")
    # the crank lengthened to 0.06 m without moving the slider: its loop cannot close
    long_crank = MODEL_PATH.read_text()
    for old, new in (
        ('name="crank_pin" pos="0 0 0.05"', 'name="crank_pin" pos="0 0 0.06"'),
        ('<body name="rod" pos="0 0 0.05">', '<body name="rod" pos="0 0 0.06">'),
    ):
        long_crank = long_crank.replace(old, new)
    (d / "long_crank.xml").write_text(long_crank)
    unmeasured = json.loads(ocp.read_text())
    del unmeasured["geometry"]
    (d / "no_geometry.json").write_text(json.dumps(unmeasured))
    unmeasured["geometry"] = {"crank_length": 0.5, "rod_length": 0.3}
    (d / "locked.json").write_text(json.dumps(unmeasured))
    refused = json.loads(ocp.read_text()) | {"refused": {"robust-fb": "the spread is too wide"}}
    (d / "refused.json").write_text(json.dumps(refused))
    failed = {"format": "crank-ocp-failed", "status": "failed", "error": "no robust profile"}
    (d / "failed.json").write_text(json.dumps(failed))  # what a solve without a torque leaves
    (d / "nameless.xml").write_text("<mujoco/>")
    (d / "folder").mkdir()
    (d / "unrun").mkdir()  # a sweep folder none of whose leaves finished
    (d / "unrun" / "sweep.json").write_text(json.dumps({"leaves": []}))
    (d / "file").write_text("a file where a folder should be\n")
    for name, text in RANGES.items():
        (d / f"{name}.toml").write_text(text)
    for name, text in RIG_TABLES.items():
        (d / f"{name}.csv").write_text(text)
    (d / "text.parquet").write_text("not parquet\n")
    import_table(d / "rig.csv", d / "rig250.mcap", spec=ImportSpec.parse(columns=RIG, rate_hz=250))
    played = play_runs(physics, ocp, profile="robust", mode="open", runs=3, seed=1)
    rigs = d / "rigs"  # the tables beside them are not inputs of the cases
    rigs.mkdir()
    for name, options in (("runs", {}), ("short", {"keep": 60}), ("lead", {"lead": 20})):
        import_runs(played, rigs / f"{name}.mcap", **options)
    other = json.loads(ocp.read_text())
    other["geometry"]["crank_length"] = 0.04
    (d / "other_geometry.json").write_text(json.dumps(other))
    return {p.name: p for p in (*d.iterdir(), *rigs.glob("*.mcap"))} | {"dir": d}


def _snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    return {
        str(p.relative_to(folder)): (p.stat().st_size, p.stat().st_mtime_ns)
        for p in folder.rglob("*")
    }


CASES: list[tuple[str, str]] = [
    # --- usage errors (click) ---
    ("nosuchcommand", "No such command 'nosuchcommand'"),
    ("generate --bogus", "No such option: --bogus"),
    ("train --data", "Option '--data' requires an argument"),
    ("solve --seed 1.5", "Invalid value for '--seed'"),
    ("replay --runs many", "Invalid value for '--runs'"),
    ("run --seed", "Option '--seed' requires an argument"),
    ("inspect", "Missing argument"),
    ("inspect {ds.mcap} {ds.mcap}", "Got unexpected extra argument"),
    ("recover", "Missing argument"),
    ("view", "Missing argument"),
    ("study --seeds 0-1 --drift-off", "No such option: --drift-off"),
    ("heldout --runs 1e3", "Invalid value for '--runs'"),
    ("generate --seconds ten", "Invalid value for '--seconds'"),
    # --- generate ---
    ("generate --seconds 0 --out o/d.mcap", "seconds must be > 0"),
    ("generate --seconds -2 --out o/d.mcap", "seconds must be > 0"),
    ("generate --max-start-time -1 --out o/d.mcap", "max_start_time must be >= 0"),
    ("generate --max-start-time nan --out o/d.mcap", "max_start_time must be a finite number"),
    ("generate --seconds nan --out o/d.mcap", "seconds must be a finite number"),
    ("generate --seconds inf --out o/d.mcap", "seconds must be a finite number"),
    ("generate --seconds 1e9 --out o/d.mcap", "needs about 5e+05 GB of memory"),
    ("generate --seconds 1 --episode-seconds nan --out o/d.mcap", "episode_seconds must be a"),
    ("generate --episodes-per-machine 0 --out o/d.mcap", "episodes_per_machine must be an integer"),
    ("generate --episodes-per-machine 1.5", "Invalid value for '--episodes-per-machine'"),
    ("generate --seconds 1 --episode-seconds 0 --out o/d.mcap", "episode_seconds must be > 0"),
    ("generate --seconds 1 --episode-seconds -1 --out o/d.mcap", "episode_seconds must be > 0"),
    ("generate --seconds 1 --amplitude -1 --out o/d.mcap", "excitation.amplitude must be >= 0"),
    ("generate --seconds 1 --amplitude nan --out o/d.mcap", "amplitude must be a finite number"),
    ("generate --seconds 1 --seed -1 --out o/d.mcap", "seed must be"),
    ("generate --seconds 1 --seed 100000000000000000000000 --out o/d.mcap", "seed must be"),
    ("generate --seconds 1 --model {dir}/absent.xml --out o/d.mcap", "MJCF not found"),
    ("generate --seconds 1 --model {garbage.xml} --out o/d.mcap", "invalid MJCF"),
    ("generate --seconds 1 --model {long_crank.xml} --out o/d.mcap", "puts top dead centre"),
    ("run --logs L --model {long_crank.xml}", "crank (l1 = 0.06 m) and rod (l2 = 0.3 m) reach"),
    ("replay --ocp {ocp.json} --out o/r.mcap --model {long_crank.xml}", "puts top dead centre"),
    ("replay --ocp {no_geometry.json} --out o/r.mcap", "missing key 'geometry'"),
    ("replay --ocp {locked.json} --out o/r.mcap", "must be longer than the crank"),
    ("generate --seconds 1 --model {nameless.xml} --out o/d.mcap", "no joint named 'motor'"),
    ("generate --seconds 1 --model {folder} --out o/d.mcap", "cannot read MJCF"),
    ("generate --seconds 1 --variability line-20 --out o/d.mcap", "unknown variability scenario"),
    ("generate --seconds 1 --variability {swapped.toml} --out o/d.mcap", "low 0.1 > high 0.05"),
    ("generate --seconds 1 --variability {nan.toml} --out o/d.mcap", "must be a finite number"),
    ("generate --seconds 1 --variability {unknown.toml} --out o/d.mcap", "motor_wobble"),
    ("generate --seconds 1 --variability {negative.toml} --out o/d.mcap", "motor_damping"),
    ("generate --seconds 1 --variability {broken.toml} --out o/d.mcap", "broken.toml"),
    ("generate --seconds 1 --variability {drift_text.toml} --out o/d.mcap", "drift must be true"),
    ("generate --seconds 1 --episode-seconds 0.001 --out o/d.mcap", "episode_seconds must cover"),
    ("generate --seconds 1 --variability {dir}/absent.toml --out o/d.mcap", "absent.toml"),
    ("generate --seconds 1 --variability {text.txt} --out o/d.mcap", "text.txt"),
    ("generate --seconds 1 --out o/d.txt", "must end in .mcap"),
    ("generate --seconds 1 --out {folder}", "it must end in .mcap"),
    ("generate --seconds 1 --out {file}/d.mcap", "cannot write to"),
    ("generate --seconds 1 --model {garbage.xml} --out {garbage.xml}", "must end in .mcap"),
    # --- inspect ---
    ("inspect {dir}/absent.mcap", "dataset not found"),
    ("inspect {text.mcap}", "not an MCAP file"),
    ("inspect {empty.mcap}", "not an MCAP file"),
    ("inspect {text.txt}", "not an MCAP file"),
    ("inspect {folder}", "folder"),
    ("inspect {m.pt}", "not an MCAP file"),
    # --- train ---
    ("train --data {dir}/absent.mcap --out o/m.pt", "dataset not found"),
    ("train --data {text.mcap} --out o/m.pt", "not an MCAP file"),
    ("train --data {empty.mcap} --out o/m.pt", "not an MCAP file"),
    ("train --data {folder} --out o/m.pt", "folder"),
    ("train --data {ds.mcap} --out o/m.txt", "must end in .pt"),
    ("train --data {ds.mcap} --out {ds.mcap}", "must end in .pt"),
    ("train --data {ds.mcap} --out {folder}", "folder"),
    ("train --data {ds.mcap} --out {file}/m.pt", "cannot write to"),
    ("train --data {ds.mcap} --out o/m.pt --seed -1", "seed must be"),
    ("train --data {ds.mcap} --out o/m.pt --seed 100000000000000000000000", "seed must be"),
    ("train --data {ds.mcap} --out o/m.pt --sigma-block 0", "sigma_block must be an integer"),
    ("train --data {ds.mcap} --out o/m.pt --bound-lines 50", "bound_lines must be 0 or at least"),
    ("train --data {ds.mcap} --out o/m.pt --early-stopping best", "early_stopping must be one of"),
    ("train --data {ds.mcap} --out o/m.pt --machine-terms motor", "machine_terms must be one of"),
    ("train --data {ds.mcap} --out o/m.pt --white-inertia exact", "white_inertia must be one of"),
    ("train --data {ds.mcap} --out o/m.pt --angle-update midpoint", "angle_update must be one of"),
    ("train --data {ds.mcap} --out o/m.pt --sigma-block -3", "sigma_block must be an integer"),
    ("train --data {ds.mcap} --out o/m.pt --epoch-windows 0", "epoch_windows must be an integer"),
    ("train --data {ds.mcap} --out o/m.pt --epochs 0", "epochs must be"),
    ("train --data {ds.mcap} --out o/m.pt --epochs -5", "epochs must be"),
    ("train --data {ds.mcap} --out o/m.pt --sigma-epochs -1", "sigma_epochs must be"),
    ("train --data {ds.mcap} --out o/m.pt --horizon 0", "horizon must be"),
    ("train --data {ds.mcap} --out o/m.pt --horizon -2", "horizon must be"),
    ("train --data {ds.mcap} --out o/m.pt --horizon 100000", "horizon"),
    # --- solve ---
    ("solve --model {dir}/absent.pt --out o/ocp.json", "not found"),
    ("solve --model {text.pt} --out o/ocp.json", "text.pt"),
    ("solve --model {cut.pt} --out o/ocp.json", "cut.pt"),
    ("solve --model {folder} --out o/ocp.json", "folder"),
    ("solve --model {ds.mcap} --out o/ocp.json", "ds.mcap"),
    ("solve --model {m.pt} --out o/ocp.txt", "must end in .json"),
    ("solve --model {m.pt} --out {m.pt}", "must end in .json"),
    ("solve --model {m.pt} --out {file}/ocp.json", "cannot write to"),
    ("solve --model {m.pt} --out o/ocp.json --horizon 2", "horizon must be >= 3 samples"),
    ("solve --model {m.pt} --out o/ocp.json --horizon 0", "horizon must be >= 3 samples"),
    ("solve --model {m.pt} --out o/ocp.json --height nan", "height must be a finite number"),
    ("solve --model {m.pt} --out o/ocp.json --height inf", "height must be a finite number"),
    ("solve --model {m.pt} --out o/ocp.json --samples 0,200", "outside 2..149"),
    ("solve --model {m.pt} --out o/ocp.json --samples 50,50", "must be distinct"),
    ("solve --model {m.pt} --out o/ocp.json --samples x", "--samples"),
    ("solve --model {m.pt} --out o/ocp.json --samples ''", "--samples"),
    ("solve --model {m.pt} --out o/ocp.json --samples 50,,100", "--samples"),
    ("solve --model {m.pt} --out o/ocp.json --samples 1", "outside 2..149"),
    ("solve --model {m.pt} --out o/ocp.json --k-sigma -1", "k_sigma must be >= 0"),
    ("solve --model {m.pt} --out o/ocp.json --k-sigma nan", "k_sigma must be a finite number"),
    ("solve --model {m.pt} --out o/ocp.json --mc-mode often", "Monte-Carlo mode must be one of"),
    ("solve --model {m.pt} --out o/ocp.json --tightening mean", "tightening must be one of"),
    ("solve --model {m.pt} --out o/ocp.json --tail-remedy more", "tail_remedy must be one of"),
    ("solve --model {m.pt} --out o/ocp.json --mc-samples 100000000", "mc_samples must be an"),
    ("solve --model {m.pt} --out o/ocp.json --mc-samples -5", "mc_samples must be an"),
    ("solve --model {m.pt} --out o/ocp.json --mc-samples 1", "mc_samples must be >= 2"),
    (
        "solve --model {m.pt} --out o/ocp.json --tightening quantile --mc-samples 1000",
        "needs >= 14816 Monte-Carlo samples",
    ),
    ("solve --model {m.pt} --out o/ocp.json --confidence 1", "confidence must be in [0, 1)"),
    ("solve --model {m.pt} --out o/ocp.json --confidence -0.1", "confidence must be >= 0"),
    ("solve --model {m.pt} --out o/ocp.json --confidence nan", "confidence must be a finite"),
    (
        "solve --model {m.pt} --out o/ocp.json --profiles robust,pid",
        "profiles must be distinct names among robust, robust-fb, robust-pd, got robust, pid",
    ),
    (
        "solve --model {m.pt} --out o/ocp.json --profiles robust-fb,robust-fb",
        "profiles must be distinct names among robust, robust-fb, robust-pd, "
        "got robust-fb, robust-fb",
    ),
    (
        "solve --model {m.pt} --out o/ocp.json --profiles ,",
        "profiles must be distinct names among robust, robust-fb, robust-pd, got none",
    ),
    (
        "solve --model {m.pt} --out o/ocp.json --fallback robust-fb,open",
        "fallback must be distinct names among robust, robust-fb, robust-pd (or none), got "
        "robust-fb, open",
    ),
    ("solve --model {m.pt} --out o/ocp.json --torque-limit 0", "torque_limit must be > 0"),
    ("solve --model {m.pt} --out o/ocp.json --pd-kp -1", "pd_kp must be >= 0"),
    ("solve --model {m.pt} --out o/ocp.json --pd-kd nan", "pd_kd must be a finite"),
    ("solve --model {m.pt} --out o/ocp.json --torque-limit nan", "torque_limit must be a finite"),
    ("solve --model {m.pt} --out o/ocp.json --torque-limit -3", "torque_limit must be > 0"),
    ("solve --model {m.pt} --out o/ocp.json --theta-start nan", "theta_start must be a finite"),
    ("solve --model {m.pt} --out o/ocp.json --theta-end inf", "theta_end must be a finite"),
    ("solve --model {m.pt} --out o/ocp.json --seed -1", "mc_seed must be"),
    # --- replay ---
    ("replay --ocp {dir}/absent.json --out o/r.mcap --runs 2", "not found"),
    ("replay --ocp {text.json} --out o/r.mcap --runs 2", "text.json"),
    ("replay --ocp {list.json} --out o/r.mcap --runs 2", "list.json"),
    ("replay --ocp {other.json} --out o/r.mcap --runs 2", "not a crank-ocp file"),
    ("replay --ocp {folder} --out o/r.mcap --runs 2", "folder"),
    ("replay --ocp {ocp.json} --out o/r.mcap --runs 0", "runs must be an integer 1..100000"),
    ("replay --ocp {ocp.json} --out o/r.mcap --runs -3", "runs must be an integer 1..100000"),
    ("replay --ocp {ocp.json} --out o/r.mcap --runs 1000000", "runs must be an integer"),
    ("replay --ocp {ocp.json} --out o/r.mcap --runs 100000", "GB of memory, this machine has"),
    ("replay --ocp {ocp.json} --out o/r.mcap --variability line-99", "unknown variability"),
    ("replay --ocp {ocp.json} --out o/r.mcap --variability {swapped.toml}", "low 0.1 > high"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes open,sideways", "modes must be a non-empty"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes ''", "modes must be a non-empty"),
    ("replay --ocp {ocp.json} --out o/r.mcap --kp nan", "kp must be a finite number, got nan"),
    ("replay --ocp {ocp.json} --out o/r.mcap --kd -1", "kd must be >= 0"),
    ("replay --ocp {ocp.json} --out o/r.mcap --feedback pid", "feedback must be one of lqr, pd"),
    ("replay --ocp {ocp.json} --out o/r.mcap --max-start-time -1", "max_start_time"),
    ("replay --ocp {ocp.json} --out o/r.mcap --max-start-time nan", "max_start_time"),
    ("replay --ocp {ocp.json} --out o/r.mcap --seed -1", "seed must be"),
    ("replay --ocp {ocp.json} --out o/r.mcap --model {garbage.xml}", "invalid MJCF"),
    ("replay --ocp {ocp.json} --out {file}/r.mcap", "cannot write"),
    ("replay --ocp {ocp.json} --out o/r.txt", "must end in .mcap"),
    ("replay --ocp {ocp.json} --out {ocp.json}", "must end in .mcap"),
    ("replay --ocp {ocp.json} --out {folder}", "folder"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --mpc-weights -1,1,1", "q_theta must be"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --mpc-weights 1,nan,1", "finite number"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --mpc-weights 1,0,0", "not determined"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --mpc-weights 1,2", "three numbers"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --mpc-horizon 150", "plan's 149 steps"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --mpc-horizon 0", "mpc horizon must"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --mpc-deadline-ms 0", "deadline must"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc", "is not there"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --ppann {m.pt}", "is not the checkpoint"),
    ("replay --ocp {ocp.json} --out o/r.mcap --modes mpc --ppann {text.pt}", "is not the check"),
    ("replay --ocp {ocp.json} --out o/r.mcap --feedback pd --ppann {m.pt}", "is not the check"),
    ("replay --ocp {ocp.json} --out o/r.mcap --feedback pd --ppann {dir}/no.pt", "is not there"),
    # --- heldout ---
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --runs 0", "runs must be an"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --runs 1000000", "runs must be"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --runs 100000", "GB of memory"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.txt", "must end in .json"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out {ocp.json}", "would overwrite"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out {file}/h.json", "cannot write"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --modes sideways", "modes must be"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --trajectories 99", "trajectories"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --trajectories 1e4", "Invalid value"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --modes open,open", "modes repeat"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --modes ,", "modes must be"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --seed -1", "seed must be"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --second-stage -1", "second_stage"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --second-stage 100001", "second_s"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --kp inf", "kp must be a finite"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --kd -0.5", "kd must be >= 0"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --modes mpc --mpc-horizon 0", "mpc h"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --modes mpc --mpc-horizon 200", "149"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --modes mpc --mpc-weights x", "three"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --variability x", "unknown variab"),
    ("heldout --ocp {dir}/absent.json --model {m.pt} --out o/h.json", "not found"),
    ("heldout --ocp {text.json} --model {m.pt} --out o/h.json", "text.json"),
    ("heldout --ocp {ocp.json} --model {dir}/absent.pt --out o/h.json", "not found"),
    ("heldout --ocp {ocp.json} --model {text.pt} --out o/h.json", "text.pt"),
    ("heldout --ocp {ocp.json} --model {m.pt} --out o/h.json --mjcf {nameless.xml}", "motor"),
    # --- recover ---
    ("recover {dir}/absent.mcap o/r.mcap", "not found"),
    ("recover {text.mcap} o/r.mcap", "text.mcap"),
    ("recover {ds.mcap} o/r.mcap", "not a campaign"),
    ("recover {folder} o/r.mcap", "folder"),
    ("recover {ds.mcap} o/r.txt", "must end in .mcap"),
    ("recover {ds.mcap} {ds.mcap}", "would overwrite"),
    # --- view ---
    ("view {dir}/absent.rrd --web --port 80", "--port must be in 1024..65534, got 80"),
    ("view {dir}/absent.rrd --web --port x", "Invalid value for '--port'"),
    ("view {dir}/absent.rrd", "not found"),
    ("view {text.txt}", "text.txt"),
    ("view {folder}", "folder"),
    # --- run ---
    ("run --logs L --name ../escaped", "--name must be a plain folder name"),
    ("run --logs L --name /tmp/absolute-run", "--name must be a plain folder name"),
    ("run --logs L --name a/b", "--name must be a plain folder name"),
    ("run --logs L --name ..", "--name must be a plain folder name"),
    ("run --logs L --name ''", "--name must be a plain folder name"),
    ("run --logs L --seconds 0", "seconds must be > 0"),
    ("run --logs L --seconds nan", "seconds must be a finite number"),
    ("run --logs L --seconds 1e9", "needs about 5e+05 GB of memory"),
    ("run --logs L --episode-seconds 0", "episode_seconds must be > 0"),
    ("run --logs L --episodes-per-machine 0", "episodes_per_machine must be an integer >= 1"),
    ("run --logs L --confidence -0.5", "confidence must be >= 0"),
    ("run --logs L --confidence nan", "confidence must be a finite number"),
    ("run --logs L --confidence 1", "confidence must be in [0, 1)"),
    ("run --logs L --variability wide", "unknown variability scenario 'wide'"),
    ("run --logs L --variability {swapped.toml}", "low 0.1 > high 0.05"),
    ("run --logs L --heldout-runs 1000000", "heldout_runs must be an integer"),
    ("run --logs L --heldout-runs 100000", "a held-out check on 100000 machines needs about"),
    ("run --logs L --runs 100000", "a campaign of 100000 runs needs about 105 GB"),
    ("run --logs L --heldout-runs -1", "heldout_runs must be an integer"),
    ("run --logs L --heldout-second-stage -1", "heldout_second_stage must be an integer"),
    ("run --logs L --heldout-trajectories 50", "heldout_trajectories must be an integer 100.."),
    ("run --logs L --heldout-trajectories 2000000", "heldout_trajectories must be an integer"),
    ("run --logs L --runs 0", "runs must be an integer"),
    ("run --logs L --seed -1", "seed must be"),
    (
        "run --logs L --profiles pid",
        "profiles must be distinct names among robust, robust-fb, robust-pd",
    ),
    ("run --logs L --fallback pid", "fallback must be distinct names among robust, robust-fb"),
    ("run --logs L --model {garbage.xml}", "invalid MJCF"),
    ("run --logs {file}", "cannot write"),
    ("run --resume {folder}", "nothing to resume: "),
    ("run --resume {dir}/absent", "nothing to resume: "),
    ("run --resume {folder} --seconds 5", "drop --seconds"),
    ("run --resume {folder} --no-drift", "drop --drift"),
    ("run --resume {folder} --config {cfg_range.toml}", "drop --config"),
    ("run --resume {folder} --profiles robust-fb", "nothing to resume: "),
    ("run --resume {folder} --pd 1,2,3", "--pd takes the gains as KP,KD"),
    ("run --logs L --config {cfg_unknown.toml}", "unknown key 'ocp.heigth'"),
    ("run --logs L --config {cfg_type.toml}", 'ocp.horizon must be an integer, got "x"'),
    ("run --logs L --config {cfg_range.toml}", "horizon must be >= 3 samples"),
    ("run --logs L --config {cfg_pd.toml}", "robust-pd's tube is sized for the PD Kp 30"),
    ("run --logs L --config {cfg_scheme.toml}", "margin_scheme must be one of aware, bracket"),
    ("run --logs L --config {cfg_no_samples.toml}", "constraint_samples must name at least one"),
    ("run --logs L --seconds 1e300", "a dataset of 5e+302 samples (1e+300 s) needs about"),
    ("run --logs L --pd x", "--pd takes the gains as KP,KD, e.g. 20,0.5; got 'x'"),
    ("run --logs L --pd 1,2,3", "--pd takes the gains as KP,KD"),
    ("run --logs L --pd 30,-1", "pd_kd must be >= 0, got -1.0"),
    ("run --logs L --config {broken.toml}", "is not TOML"),
    ("run --logs L --config {dir}/absent.toml", "cannot read config"),
    ("run --logs L --config {folder}", "cannot read config"),
    ("config --config {cfg_unknown.toml}", "unknown key 'ocp.heigth'"),
    ("run --logs L --config {cfg_old.toml}", "'ocp.feedback' (replaced by ocp.profiles: feedback"),
    ("config --config {cfg_range.toml}", "horizon must be >= 3 samples"),
    ("run --logs L --config {cfg_stop.toml}", "early_stopping must be one of tail, machines"),
    ("run --logs L --config {cfg_terms.toml}", "machine_terms must be one of augmented, prior"),
    ("run --logs L --config {cfg_plan.toml}", "plan.dither must be a finite number, got nan"),
    ("run --logs L --config {cfg_plan_many.toml}", "plan.episodes must be an integer 0..10000"),
    ("run --logs L --plan-episodes -3", "plan.episodes must be an integer 0..10000, got -3"),
    ("config --config {text.txt}", "is not TOML"),
    # --- study ---
    ("study --out S --seeds ''", "--seeds takes a range like 0-9"),
    ("study --out S --seeds 0-", "--seeds takes a range like 0-9"),
    ("study --out S --seeds 5-2", "runs backwards"),
    ("study --out S --seeds 1,1", "repeats a seed"),
    ("study --out S --episodes-per-machine -2", "episodes_per_machine must be an integer >= 1"),
    ("study --out S --fallback robust,pid", "fallback must be distinct names among robust"),
    ("study --out S --seeds x", "--seeds takes a range like 0-9"),
    ("study --out S --seeds -1", "--seeds takes a range like 0-9"),
    ("study --out S --seeds 0-5000", "--seeds must name 1..1000 seeds"),
    ("study --out S --seeds 0-1 --tightening mean", "tightening must be one of"),
    ("study --out S --seeds 0-1 --mc-mode often", "Monte-Carlo mode must be one of"),
    ("study --out S --seeds 0-1 --confidence 1", "confidence must be in [0, 1), got 1"),
    ("study --out S --seeds 0-1 --heldout-runs -1", "heldout_runs must be an integer"),
    ("study --out S --seeds 0-1 --variability line-99", "unknown variability scenario"),
    ("study --out S --seeds 0-1 --seconds 0", "seconds must be > 0"),
    ("study --out S --seeds 0-1 --runs 0", "runs must be an integer"),
    ("study --out S --seeds 0-1 --plan-episodes -3", "plan.episodes must be an integer 0..10000"),
    ("study --out S --seeds 0-1 --pd 20", "--pd takes the gains as KP,KD"),
    (
        "study --out S --seeds 0-1 --profiles nominal",
        "profiles must be distinct names among robust, robust-fb, robust-pd, got nominal",
    ),
    ("study --out {file}/S --seeds 0-1", "cannot write"),
    ("study --out S --seeds 0-1 --config {cfg_unknown.toml}", "unknown key 'ocp.heigth'"),
    ("study --out S --seeds 0-1 --config {cfg_range.toml}", "horizon must be >= 3 samples"),
    ("study --out S --seeds 0-1 --config {broken.toml}", "is not TOML"),
    ("study --out S --seeds 0- --config {cfg_range.toml}", "--seeds takes a range like 0-9"),
    # --- export ---
    ("export {ocp.json} --out o/p.csv --profile robust-pd", "has no profile 'robust-pd' (it has"),
    ("export {refused.json} --out o/p.csv --profile robust-fb", "robust-fb was refused in this"),
    ("export {ocp.json} --out o/p.txt", "must end in .csv"),
    ("export {ocp.json} --out {ocp.json}", "must end in .csv"),
    ("export {text.json} --out o/p.csv", "not a JSON file"),
    ("export {failed.json} --out o/p.csv", "the record of a solve that found no robust torque"),
    ("replay --ocp {failed.json} --out o/r.mcap", "crank-ocp-failed: its error, nominal plan"),
    ("export {other.json} --out o/p.csv", "not a crank-ocp file"),
    ("export {dir}/absent.json --out o/p.csv", "OCP file not found"),
    ("export {ocp.json} --out o/p.csv --units tau=kN*m", "--units: tau in 'kN*m'? use one of"),
    ("export {ocp.json} --out o/p.csv --units force=N", "--units: unknown field 'force'"),
    ("export {ocp.json} --out o/p.csv --units tau", "--units: 'tau' is not field=value"),
    ("export {ocp.json} --out o/p.csv --flip t", "--flip: 't' has no sign here"),
    ("export {ocp.json} --out {file}/p.csv", "cannot write"),
    # --- verify ---
    ("verify {ocp.json} {ds.mcap} --out o/v.json", "did not play profile robust: its torque is"),
    ("verify {ocp.json} {lead.mcap} --out o/v.json", "it is nearest from its sample 21 (t = 0.04"),
    ("verify {ocp.json} {short.mcap} --out o/v.json", "has 59 samples; the constraint's last is"),
    ("verify {ocp.json} {rig250.mcap} --out o/v.json", "again with --rate 500"),
    ("verify {other_geometry.json} {runs.mcap} --out o/v.json", "a mechanism with l1 = 0.04 m"),
    ("verify {ocp.json} {runs.mcap} --profile robust-pd --out o/v.json", "has no profile"),
    ("verify {refused.json} {runs.mcap} --profile robust-fb --out o/v.json", "was refused"),
    ("verify {failed.json} {runs.mcap} --out o/v.json", "found no robust torque"),
    ("verify {text.json} {runs.mcap} --out o/v.json", "not a JSON file"),
    ("verify {dir}/absent.json {runs.mcap} --out o/v.json", "OCP file not found"),
    ("verify {ocp.json} {dir}/absent.mcap --out o/v.json", "dataset not found"),
    ("verify {ocp.json} {text.mcap} --out o/v.json", "not an MCAP file"),
    ("verify {ocp.json} {runs.mcap} --align best --out o/v.json", "--align must be one of start,"),
    ("verify {ocp.json} {runs.mcap} --played-tolerance 0 --out o/v.json", "must be within (0, 1]"),
    ("verify {ocp.json} {runs.mcap} --played-tolerance nan --out o/v.json", "within (0, 1]"),
    ("verify {ocp.json} {runs.mcap} --out o/v.txt", "it must end in .json"),
    ("verify {ocp.json} {runs.mcap} --out {ocp.json}", "would overwrite the ocp_path"),
    ("verify {ocp.json} {runs.mcap} --out {file}/v.json", "cannot write"),
    ("verify {ocp.json} --out o/v.json", "Missing argument"),
    ("verify {ocp.json} {runs.mcap} --control-rate 750 --out o/v.json", "a whole multiple of"),
    ("verify {ocp.json} {runs.mcap} --control-rate 0 --out o/v.json", "--control-rate must be"),
    ("verify {ocp.json} {runs.mcap} --control-rate nan --out o/v.json", "got nan"),
    ("verify {ocp.json} {runs.mcap} --control-rate 1e6 --out o/v.json", "up to 32000 Hz"),
    ("verify {ocp.json} {runs.mcap} --ppann {dir}/no.pt --out o/v.json", "no.pt is not there"),
    ("verify {ocp.json} {runs.mcap} --ppann {m.pt} --out o/v.json", "is not the checkpoint"),
    ("verify {ocp.json} {runs.mcap} --ppann {m.pt} --out {m.pt}", "it must end in .json"),
    # --- import ---
    (
        "import {rig.csv} --map t=time,theta=enc,tau=cmd,omega=speed --out o/r.mcap",
        "no column 'speed' (columns: time, enc, cmd)",
    ),
    ("import {gap.csv} --map " + RIG + " --out o/r.mcap", "a gap of 101 ms at t = 0.099 s"),
    (
        "import {nan.csv} --map " + RIG + " --out o/r.mcap",
        "column 'cmd' (tau) is not finite at 7 row(s)",
    ),
    ("import {back.csv} --map " + RIG + " --out o/r.mcap", "time does not increase at data row 51"),
    (
        "import {word.csv} --map " + RIG + " --out o/r.mcap",
        "line 2, column 'cmd': 'half' is not a number",
    ),
    ("import {jitter.csv} --map " + RIG + " --out o/r.mcap", "it is not one rate"),
    ("import {few.csv} --map " + RIG + " --out o/r.mcap", "2 rows; a dataset needs at least 3"),
    ("import {rig.csv} --map t=time,theta=enc --out o/r.mcap", "--map must name a column for tau"),
    (
        "import {rig.csv} --map t=time,theta=enc,tau=cmd,torque=cmd --out o/r.mcap",
        "unknown field 'torque'",
    ),
    ("import {rig.csv} --map t --out o/r.mcap", "--map: 't' is not field=value"),
    ("import {rig.csv} --map " + RIG + " --units theta=grad --out o/r.mcap", "theta in 'grad'?"),
    (
        "import {rig.csv} --map " + RIG + " --flip episode --out o/r.mcap",
        "the episode column has no sign",
    ),
    (
        "import {rig.csv} --map " + RIG + " --flip machine --out o/r.mcap",
        "the machine column has no sign",
    ),
    (
        "import {rig.csv} --map " + RIG + ",machine=cmd --out o/r.mcap",
        "the machine column holds non-integers",
    ),
    (
        "import {rig.csv} {few.csv} --map " + RIG + " --machines A --out o/r.mcap",
        "--machines: 1 label(s) for 2 file(s)",
    ),
    (
        "import {rig.csv} --map " + RIG + ",machine=cmd --machines A --out o/r.mcap",
        "--machines names each file's machine: not with a machine column",
    ),
    (
        "import {rig.csv} --map " + RIG + " --rate 0 --out o/r.mcap",
        "--rate must be within 1-100000 Hz",
    ),
    (
        "import {rig.csv} --map " + RIG + " --rate nan --out o/r.mcap",
        "--rate must be within 1-100000 Hz",
    ),
    ("import {rig.csv} --map " + RIG + " --max-gap 1 --out o/r.mcap", "--max-gap must be above 1"),
    (
        "import {rig.csv} --map " + RIG + " --rate 20 --out o/r.mcap",
        "too short for two samples at 20 Hz",
    ),
    ("import {dir}/absent.csv --map " + RIG + " --out o/r.mcap", "rig data not found"),
    ("import {rig.csv} {dir}/absent.csv --map " + RIG + " --out o/r.mcap", "absent.csv"),
    ("import {rig.csv} {rig.csv} --map " + RIG + " --out o/r.mcap", "rig.csv is named twice"),
    ("import {rig.csv} {ds.mcap} --map " + RIG + " --out {ds.mcap}", "would overwrite the data"),
    (
        "import {text.txt} --map " + RIG + " --out o/r.mcap",
        "rig data must be .csv, .parquet or .mcap",
    ),
    ("import {text.parquet} --map " + RIG + " --out o/r.mcap", "not a Parquet file"),
    ("import {rig.csv} --map " + RIG + " --out o/r.json", "it must end in .mcap"),
    ("import {rig.csv} --map " + RIG + " --out {file}/r.mcap", "cannot write"),
    ("import {rig.csv} --map " + RIG + " --model {garbage.xml} --out o/r.mcap", "invalid MJCF"),
    ("import {rig.csv} --out o/r.mcap", "Missing option '--map'"),
    ("import {text.mcap} --map t=log_time,theta=/m.p,tau=/c.t --out o/r.mcap", "not an MCAP file"),
    (
        "import {ds.mcap} --map t=log_time,theta=/m.p,tau=/c.t --out o/r.mcap",
        "no topic /m (topics: ",
    ),
    (
        "train --data {rig250.mcap} --out o/m.pt",
        "the PPANN steps at 500 Hz; import the data again with --rate 500",
    ),
    # --- sweep ---
    ("sweep {sw_unknown.toml} --out S", "unknown key 'ocp.heigth'"),
    ("sweep {sw_base_unknown.toml} --out S", "unknown key 'seeds'"),
    ("sweep {sw_section.toml} --out S", "unknown section 'grids'"),
    ("sweep {sw_empty.toml} --out S", "empty grid: give [grid] values or [[cases]]"),
    ("sweep {sw_axis.toml} --out S", "empty grid: [grid] seed must be a non-empty list"),
    ("sweep {sw_scalar.toml} --out S", "empty grid: [grid] seed must be a non-empty list"),
    ("sweep {sw_range.toml} --out S", "leaf ocp.horizon=2: horizon must be >= 3 samples"),
    ("sweep {sw_seed.toml} --out S", "seed must be"),
    ("sweep {sw_type.toml} --out S", 'ocp.height must be a number, got "high"'),
    ("sweep {sw_same.toml} --out S", "are the same run"),
    ("sweep {sw_names.toml} --out S", "two cases share a name"),
    ("sweep {sw_cases.toml} --out S", "cases must be an array of tables"),
    ("sweep {sw_big.toml} --out S", "10010 leaves, more than 10000"),
    ("sweep {broken.toml} --out S", "is not TOML"),
    ("sweep {dir}/absent.toml --out S", "cannot read sweep spec"),
    ("sweep {dir} --out S", "is a folder: give its TOML file, or continue a sweep folder with"),
    ("sweep --out S", "give the sweep's spec file"),
    ("sweep {sw_ok.toml} --out S --executor dask", "executor must be one of ray, sequential"),
    ("sweep {sw_ok.toml} --out S --workers 0", "--workers must be >= 1"),
    ("sweep {sw_ok.toml} --out {dir}", "sweep folder already exists"),
    ("sweep {sw_ok.toml} --out {file}/S", "cannot write"),
    ("sweep --resume {dir}", "nothing to resume: "),
    ("sweep {sw_ok.toml} --resume {dir}", "give no spec"),
    ("compare {dir} --out o/c", "is not a finished run folder (no config.json)"),
    ("compare {dir}/absent --out o/c", "is not a finished run folder"),
    ("compare {dir} {dir} --out o/c", "a run folder is named twice"),
    ("compare {unrun} --out o/c", "has no finished leaf to compare"),
    ("compare {dir} --merge --out o/c", "--merge needs at least two compare folders"),
    ("compare {dir} {dir}/absent --merge --out o/c", "is not a compare folder (no compare.json)"),
]


def _argv(case: str, inputs: dict[str, Path]) -> list[str]:
    """The case's words with {name} replaced by the input's path and '' by an empty word."""
    words = []
    for word in case.split(" "):
        for name, path in inputs.items():
            word = word.replace("{" + name + "}", str(path))
        words.append("" if word == "''" else word)
    return words


@pytest.mark.parametrize(("case", "match"), CASES, ids=[c for c, _ in CASES])
def test_bad_input_is_one_line_and_writes_nothing(
    case: str,
    match: str,
    inputs: dict[str, Path],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", ["crank", *_argv(case, inputs)])
    before = _snapshot(inputs["dir"])
    with pytest.raises(SystemExit) as ended:
        main()
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert ended.value.code == 2, err
    assert "Traceback" not in err and "Traceback" not in out
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert match in lines[0], lines[0]
    assert os.listdir(tmp_path) == [], "a refused command left files in the working folder"
    assert _snapshot(inputs["dir"]) == before, "a refused command touched its inputs' folder"


@pytest.mark.parametrize("command", ["run --logs L --seconds 2", "generate --out d.mcap"])
def test_a_bad_rollout_thread_count_in_the_environment_is_one_line(
    command: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """$CRANK_ROLLOUT_THREADS (common/threads.py) is checked before a command writes anything."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("CRANK_ROLLOUT_THREADS", "many")
    monkeypatch.setattr(sys, "argv", ["crank", *command.split()])
    with pytest.raises(SystemExit) as ended:
        main()
    lines = capsys.readouterr().err.strip().splitlines()
    assert ended.value.code == 2
    assert lines == ["error: $CRANK_ROLLOUT_THREADS must be an integer >= 1, got 'many'"]
    assert os.listdir(tmp_path) == []


def test_the_table_covers_every_subcommand_with_130_cases() -> None:
    commands = {c.split(" ")[0] for c, _ in CASES}
    expected = {"generate", "inspect", "train", "solve", "replay", "heldout", "recover", "view"}
    assert commands >= expected | {"run", "study", "config", "sweep", "import", "export", "verify"}
    assert "compare" in commands
    assert len(CASES) >= 130 and len({c for c, _ in CASES}) == len(CASES)
