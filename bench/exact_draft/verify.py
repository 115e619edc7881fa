"""Re-solve C's and D's tasks (and E's paper torques, where present) with main's code and compare
with the torques g52 wrote: the held-out evidence applies to main's code where they are equal."""
import json, sys, tempfile
from pathlib import Path
import numpy as np
sys.path.insert(0, "/work/main/bench")
from bench_tasks import TASKS
from control.config import OCPConfig
from control.solve import solve_file
from common.errors import CrankError

pairs = [(s, s) for s in range(5)] + [(3, m) for m in range(5) if m != 3]
tmp = Path(tempfile.mkdtemp())
for s, m in pairs:
    model = Path(f"/work/e50/models/s{s}/model.pt")
    for t, (task, options) in enumerate(TASKS.items()):
        config = OCPConfig(**options, mc_seed=m)
        old = model.parent / "tasks" / f"task{t}-mc{m}.json"
        try:
            new = solve_file(model, tmp / f"s{s}-t{t}-m{m}.json", config=config)
        except CrankError as exc:
            print(f"s{s} t{t} mc{m}: refused now ({str(exc)[:60]}); before: {'file' if old.exists() else 'none'}", flush=True)
            continue
        a = json.load(open(old))["robust"]
        b = json.load(open(tmp / f"s{s}-t{t}-m{m}.json"))["robust"]
        d = float(np.max(np.abs(np.array(a["tau"]) - np.array(b["tau"]))))
        print(f"s{s} t{t} mc{m}: max|dtau| {d:.3g}, k {a.get('k_sigma')} / {b.get('k_sigma')}", flush=True)
for s in range(5):  # B: the paper task's torques of crank solve --seed S
    b = json.load(open(f"/work/r52/b/{s}/ocp.json"))["robust"]["tau"]
    c = json.load(open(tmp / f"s{s}-t0-m{s}.json"))["robust"]["tau"]
    print(f"B s{s}: max|dtau| {float(np.max(np.abs(np.array(b) - np.array(c)))):.3g}", flush=True)
e = Path("/work/r52/e")
for s in range(5, 10):  # E, where run
    if (e / f"{s}/ocp.json").exists():
        model = Path(f"/work/r52/models/s{s}/model.pt")
        new = tmp / f"e{s}.json"
        solve_file(model, new, config=OCPConfig(mc_seed=s))
        a = json.load(open(e / f"{s}/ocp.json"))["robust"]["tau"]
        b = json.load(open(new))["robust"]["tau"]
        print(f"E s{s}: max|dtau| {float(np.max(np.abs(np.array(a) - np.array(b)))):.3g}", flush=True)
