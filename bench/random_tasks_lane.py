"""One lane of bench/random_tasks.md's run 2, as session 97 ran it: for each task named (in
order), wait for its solve step in run 1's sweep (its line in the sweep's log), copy that step's
final model, and run bench/bench_tasks.py on it with Monte-Carlo seeds 0-4 (`robust-fb` too where
run 1 refused the open loop). Paths and the 01:25 cutoff are the session's.

    OMP_NUM_THREADS=1 CRANK_ROLLOUT_THREADS=1 taskset -c 0 python bench/random_tasks_lane.py 0,2,4,6
"""

import datetime
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

SWEEP = Path("/tmp/s97/sweep")
LOG = Path("/work/s97_sweep.log")
tasks = [int(t) for t in sys.argv[1].split(",")]
CUTOFF = datetime.datetime(2026, 12, 7, 1, 25)


def key_of(i):
    for line in LOG.read_text().splitlines():
        m = re.match(rf"\[\d+/\d+\] solve (\w+) \(.*case=task {i}:", line)
        if m:
            return m.group(1)
    return None


for i in tasks:
    while (key := key_of(i)) is None:
        if datetime.datetime.utcnow() > CUTOFF:
            break
        time.sleep(20)
    if datetime.datetime.utcnow() > CUTOFF:
        print(f"task {i}: not started by 01:25: not run", flush=True)
        continue
    step = SWEEP / "solve" / key
    work = Path(f"/tmp/s97/mc/task{i}")
    work.mkdir(parents=True, exist_ok=True)
    shutil.copy(step / "model.pt", work / "model.pt")
    ocp = json.loads((step / "ocp.json").read_text())
    profiles = "robust,robust-fb" if "robust" in ocp.get("refused", {}) else "robust"
    print(
        f"task {i}: solve {key}, profiles {profiles}, start {datetime.datetime.utcnow():%H:%M:%S}",
        flush=True,
    )
    subprocess.run(
        [
            ".venv/bin/python",
            "bench/bench_tasks.py",
            "--model",
            str(work / "model.pt"),
            "--drawn",
            f"20261284:{i}",
            "--mc-seeds",
            "0-4",
            "--runs",
            "1000",
            "--second-stage",
            "9000",
            "--heldout-seed",
            "20261286",
            "--out",
            "mc_seeds.json",
            "--profiles",
            profiles,
        ],
        cwd="/work/run97b",
        check=False,
    )
    print(f"task {i}: end {datetime.datetime.utcnow():%H:%M:%S}", flush=True)
