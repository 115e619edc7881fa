"""crank/sweep_resume.py: a resumed sweep whose finished steps its spec no longer keys (its twin
edited, its sweep.toml edited by hand) is refused in one line naming what changed, before
anything is written; unchanged, or with a leaf added, it goes on. One real data step (a 12 s
dataset); the later steps' results are markers, since only their presence is read."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from common.errors import ConfigError
from crank.sweep import RESULT, run_node, run_sweep
from crank.sweep_resume import check_resumable
from crank.sweep_spec import KINDS, folder, graph, read_spec
from tests.conftest import crank
from tests.test_sweep import SPEC
from twin import MODEL_PATH
from twin.physics import model_sha256


def _files(out: Path) -> dict[str, int]:
    return {str(p.relative_to(out)): p.stat().st_mtime_ns for p in sorted(out.rglob("*"))}


def test_a_resume_whose_steps_changed_is_refused_naming_what_changed(tmp_path: Path) -> None:
    twin = tmp_path / "twin.xml"
    shutil.copy(MODEL_PATH, twin)
    out = tmp_path / "out"
    out.mkdir()
    spec = out / "sweep.toml"
    text = SPEC.replace("[base]\n", f'[base]\nmodel = "{twin}"\n', 1) + "[grid]\nseed = [0]\n"
    spec.write_text(text)
    _, leaves = read_spec(spec)
    (leaf,) = leaves
    data = next(n for n in graph(leaves) if n.kind == "data")
    assert "error" not in run_node(data, out)
    for kind, key in zip(KINDS[1:], leaf.steps[1:], strict=True):  # finished, as far as a
        (folder(out, kind, key)).mkdir(parents=True)  # resume can tell
        (folder(out, kind, key) / RESULT).write_text("{}")
    record = {"name": leaf.name, "steps": dict(zip(KINDS, leaf.steps, strict=True))}
    record["config"] = leaf.config.as_dict()
    (out / "sweep.json").write_text(json.dumps({"leaves": [record]}, default=str))
    check_resumable(out, leaves)  # nothing changed

    made_on = model_sha256(twin)
    twin.write_text(twin.read_text().replace("<mujoco", "<!-- edited -->\n<mujoco", 1))
    before = _files(out)
    with pytest.raises(ConfigError) as refused:
        run_sweep(None, out, executor="sequential", resume=True)
    message = str(refused.value)
    assert "4 finished steps (1 data, 1 model, 1 solve, 1 leaf)" in message
    assert f"sha256 {model_sha256(twin)[:12]}…, its dataset's {made_on[:12]}…" in message
    assert str(twin) in message and "run the sweep into a new folder" in message
    assert _files(out) == before  # nothing written
    cli = crank("sweep", "--resume", str(out), "--executor", "sequential")
    assert cli.returncode == 2 and "Traceback" not in cli.stderr
    assert cli.stderr.strip().splitlines()[-1] == f"error: {message}"
    assert _files(out) == before

    shutil.copy(MODEL_PATH, twin)  # put back: the data and model steps are found again
    spec.write_text(text.replace("runs = 4", "runs = 5"))  # the leaf's replays, by hand
    (new,) = read_spec(spec)[1]
    assert new.steps[:3] == leaf.steps[:3] and new.steps[3] != leaf.steps[3]
    with pytest.raises(ConfigError, match=r"1 finished steps \(0 data, 0 model, 0 solve, 1 leaf"):
        check_resumable(out, [new])
    changed = r"the settings of leaf 'seed=0' changed \(replay\.runs\)"
    with pytest.raises(ConfigError, match=changed):
        check_resumable(out, [new])
    # a leaf added by hand is a new leaf; the recorded one unchanged resumes
    spec.write_text(text.replace("seed = [0]", "seed = [0, 1]"))
    both = read_spec(spec)[1]
    assert len(both) == 2
    check_resumable(out, both)


def test_a_resume_whose_twin_is_gone_says_how_to_point_at_a_copy(tmp_path: Path) -> None:
    """A sweep folder moved without its twin: the resume stops at "MJCF not found" and says that
    `model` in the folder's sweep.toml may name a copy (its steps are keyed by the MJCF's bytes);
    one line, exit 2, nothing written. A copy named there keys the steps as the original."""
    out = tmp_path / "out"
    out.mkdir()
    gone = tmp_path / "gone" / "twin.xml"
    spec = out / "sweep.toml"
    spec.write_text(
        SPEC.replace("[base]\n", f'[base]\nmodel = "{gone}"\n', 1) + "[grid]\nseed = [0]\n"
    )
    before = _files(out)
    result = crank("sweep", "--resume", str(out))
    assert result.returncode == 2 and "Traceback" not in result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"error: MJCF not found: {gone}, named in {spec}: point `model` there")
    assert "its bytes key the steps" in line
    assert _files(out) == before
    copy = tmp_path / "copy.xml"  # the same bytes elsewhere: the same steps as the original's
    shutil.copy(MODEL_PATH, copy)
    spec.write_text(spec.read_text().replace(str(gone), str(copy)))
    original = tmp_path / "original.toml"
    original.write_text(spec.read_text().replace(str(copy), str(MODEL_PATH)))
    (leaf,) = read_spec(spec)[1]
    assert leaf.config.model_path == str(copy) and leaf.steps == read_spec(original)[1][0].steps
