"""Re-solve C's and D's tasks and B's paper torques with the code on the path (a5c1430) and compare
with the torques 5491058 wrote (session 52's run folders, paths as they were on that machine):
the held-out figures are that code's where the torques are equal to the bit."""

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_tasks import TASKS

from common.errors import CrankError
from control.config import OCPConfig
from control.solve import solve_file

pairs = [(s, s) for s in range(5)] + [(3, m) for m in range(5) if m != 3]
tmp = Path(tempfile.mkdtemp())
for s, m in pairs:
    model = Path(f"/work/e50/models/s{s}/model.pt")
    for t, options in enumerate(TASKS.values()):
        config = OCPConfig(**options, mc_seed=m)
        old = model.parent / "tasks" / f"task{t}-mc{m}.json"
        try:
            solve_file(model, tmp / f"s{s}-t{t}-m{m}.json", config=config)
        except CrankError as exc:
            before = "file" if old.exists() else "none"
            print(f"s{s} t{t} mc{m}: refused now ({str(exc)[:60]}); before: {before}", flush=True)
            continue
        a = json.loads(Path(old).read_text())["robust"]
        b = json.loads(Path(tmp / f"s{s}-t{t}-m{m}.json").read_text())["robust"]
        d = float(np.max(np.abs(np.array(a["tau"]) - np.array(b["tau"]))))
        print(f"s{s} t{t} mc{m}: max|dtau| {d:.3g}, k {a.get('k_sigma')} / {b.get('k_sigma')}")
for s in range(5):  # B: the paper task's torques of crank solve --seed S
    b = json.loads(Path(f"/work/r52/b/{s}/ocp.json").read_text())["robust"]["tau"]
    c = json.loads(Path(tmp / f"s{s}-t0-m{s}.json").read_text())["robust"]["tau"]
    print(f"B s{s}: max|dtau| {float(np.max(np.abs(np.array(b) - np.array(c)))):.3g}")
