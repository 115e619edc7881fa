"""Geometry from the MJCF (twin/geometry.py): read from named elements, checked for consistency,
carried by the dataset, the checkpoint and ocp.json, and a mismatch between stages refused.
End to end on a twin whose crank is 0.06 m long."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from common.errors import ConfigError
from crank.chain import run_chain
from ppann.checkpoint import load
from replay.config import ReplayConfig
from replay.files import replay_file
from replay.heldout import heldout_file
from tests.test_chain import BRIEF
from twin import MODEL_PATH
from twin.geometry import PAPER, Geometry, GeometryError
from twin.mcap_dataset import read_dataset, read_truth
from twin.physics import SliderCrank, compile_mjcf

PAPER_XML = MODEL_PATH.read_text()
LONG_CRANK = {  # l1 = 0.06 m: the arm, the pin, the rod's pivot, and the slider's reference
    'fromto="0 -0.015 0 0 -0.015 0.05"': 'fromto="0 -0.015 0 0 -0.015 0.06"',
    '<site name="crank_pin" pos="0 0 0.05"/>': '<site name="crank_pin" pos="0 0 0.06"/>',
    '<body name="rod" pos="0 0 0.05">': '<body name="rod" pos="0 0 0.06">',
    '<body name="slider" pos="0 0 0.35">': '<body name="slider" pos="0 0 0.36">',
    'type="slide" axis="0 0 1" ref="0.1"': 'type="slide" axis="0 0 1" ref="0.12"',
}


def _variant(changes: dict[str, str]) -> str:
    xml = PAPER_XML
    for old, new in changes.items():
        assert xml.count(old) == 1, old
        xml = xml.replace(old, new)
    return xml


def _geometry(xml: str) -> Geometry:
    return Geometry.of_model(compile_mjcf(xml, source="test")[0])


def test_geometry_is_read_from_the_named_elements() -> None:
    assert _geometry(PAPER_XML) == PAPER
    assert _geometry(_variant(LONG_CRANK)) == Geometry(crank_length=0.06, rod_length=0.3)
    longer_rod = _variant(
        {
            '<site name="rod_tip" pos="0 0 0.3"/>': '<site name="rod_tip" pos="0 0 0.35"/>',
            'fromto="0 -0.025 0 0 -0.025 0.3"': 'fromto="0 -0.025 0 0 -0.025 0.35"',
            '<body name="slider" pos="0 0 0.35">': '<body name="slider" pos="0 0 0.4">',
            'anchor="0 0 0.3"': 'anchor="0 0 0.35"',
        }
    )
    assert _geometry(longer_rod) == Geometry(crank_length=0.05, rod_length=0.35)


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        # the crank lengthened alone: the slider's reference no longer puts x = 0 at the bottom
        (
            {k: v for k, v in LONG_CRANK.items() if "slider" not in k},
            r"puts top dead centre at 0.35 m above the motor axis, but its crank \(l1 = 0.06 m\)",
        ),
        ({'<body name="rod" pos="0 0 0.05">': '<body name="rod" pos="0 0 0.04">'}, "rod pivots"),
        (
            {'<site name="crank_pin" pos="0 0 0.05"/>': '<site name="crank_pin" pos="0 0 0.5"/>'},
            "must be longer than the crank",
        ),
    ],
)
def test_an_inconsistent_mjcf_is_refused_naming_what_disagrees(changes, match) -> None:
    with pytest.raises((GeometryError, ConfigError), match=match):
        SliderCrank(compile_mjcf(_variant(changes), source="test")[0])


def test_kinematics_scale_with_the_crank() -> None:
    long = Geometry(crank_length=0.06, rod_length=0.3)
    assert long.stroke_top == 0.12
    assert long.slider_position(0.0) == pytest.approx(0.12, abs=1e-15)
    assert long.slider_position(np.pi) == pytest.approx(0.0, abs=1e-15)
    theta = np.linspace(0, 2 * np.pi, 101)
    np.testing.assert_allclose(long.within_stroke(long.slider_position(theta) + 1), 0.12)


def test_geometry_mismatch_names_both_mechanisms() -> None:
    long = Geometry(crank_length=0.06, rod_length=0.3)
    with pytest.raises(
        GeometryError, match=r"plan.json is for .* l1 = 0.06 m.* the twin has l1 = 0.05 m"
    ):
        long.check_same(PAPER, this="plan.json", that="the twin")
    PAPER.check_same(Geometry(0.05 + 1e-12, 0.3), this="a", that="b")  # rounding is the same


@pytest.fixture(scope="module")
def long_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The short chain of tests/test_chain.py on a twin with a 0.06 m crank."""
    root = tmp_path_factory.mktemp("long-crank")
    mjcf = root / "long_crank.xml"
    mjcf.write_text(_variant(LONG_CRANK))
    from dataclasses import replace

    config = replace(BRIEF, model_path=str(mjcf))
    run_chain(config, root / "run", argv=[])
    return root


def test_a_twin_with_a_longer_crank_runs_end_to_end(long_run: Path) -> None:
    run = long_run / "run"
    long = {"crank_length": 0.06, "rod_length": 0.3}
    dataset = read_dataset(run / "dataset.mcap")
    truth = read_truth(run / "dataset.mcap")
    assert dataset.run["geometry"] == long
    assert truth.loop_closure_error.max() < 1e-4  # the twin's own loop closes
    assert dataset.slider_position.min() >= 0.0 and dataset.slider_position.max() <= 0.1205
    assert dataset.slider_position.max() > 0.11  # it uses the 0.12 m stroke
    model, payload = load(run / "model.pt")
    assert payload["geometry"] == long and model.geometry == Geometry(**long)
    assert payload["torque_limit"] == 10.0  # the MJCF's ctrlrange, carried for solve's check
    ocp = json.loads((run / "ocp.json").read_text())
    assert ocp["geometry"] == long
    # the plan's slider is the 0.06 m kinematics of its states, and keeps the constraint
    states = np.array(ocp["robust"]["theta"])
    np.testing.assert_allclose(
        ocp["robust"]["slider"], Geometry(**long).slider_position(states), rtol=0, atol=1e-12
    )
    samples = [k - 1 for k in ocp["constraint_samples"]]
    assert min(np.array(ocp["nominal"]["slider"])[samples]) >= 0.08 - 1e-6
    report = json.loads((run / "report.json").read_text())
    assert report["heldout"]["runs"] == BRIEF.heldout_runs


def test_a_plan_for_another_mechanism_is_refused_by_the_twin(long_run: Path) -> None:
    run = long_run / "run"
    with pytest.raises(GeometryError, match=r"ocp.json is for a mechanism with l1 = 0.06 m"):
        replay_file(run / "ocp.json", long_run / "other.mcap", config=ReplayConfig(runs=2))
    with pytest.raises(GeometryError, match=r"l1 = 0.06 m.*the twin has l1 = 0.05 m"):
        heldout_file(
            run / "ocp.json",
            long_run / "other.json",
            model=run / "model.pt",
            runs=2,
            seed=1,
            variability=BRIEF.generation.variability,
        )
    assert not (long_run / "other.mcap").exists() and not (long_run / "other.json").exists()


def test_a_checkpoint_from_before_geometry_is_the_papers(tmp_path: Path, long_run: Path) -> None:
    payload = torch.load(long_run / "run" / "model.pt", weights_only=True)
    del payload["geometry"]
    torch.save(payload, tmp_path / "old.pt")
    model, _ = load(tmp_path / "old.pt")
    assert model.geometry == PAPER


def test_a_plan_asking_more_torque_than_the_models_twin_is_refused(tmp_path: Path) -> None:
    """The checkpoint carries its twin's actuator limit; solve refuses a larger torque_limit
    before any work, and takes the twin's own."""
    from control.config import OCPConfig, OCPConfigError
    from control.solve import solve_file
    from ppann.checkpoint import save
    from ppann.model import constant_ppann

    model = tmp_path / "m.pt"
    ppann = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    save(model, ppann, kind="ppann", extra={"history": {}, "torque_limit": 8.0})
    with pytest.raises(OCPConfigError, match=r"torque_limit 10 N·m exceeds the actuator limit 8"):
        solve_file(model, tmp_path / "ocp.json", config=OCPConfig())
    assert not (tmp_path / "ocp.json").exists()


@pytest.mark.parametrize("geometry", [PAPER, Geometry(0.03, 0.12)])
def test_the_crank_reach_inverts_the_slider_position(geometry) -> None:
    """crank_reach(x) is the angle at which the slider is at x (to 1e-12 m), with the slider at
    or above x just inside it and below just outside, on either side of top dead centre; a
    quarter turn where x is the slider's position at a quarter turn, sqrt(l2^2 - l1^2) + l1 -
    l2; pi at and below the stroke's bottom, 0 at its top, -inf above it."""
    x = np.linspace(1e-4, geometry.stroke_top - 1e-4, 101)
    reach = geometry.crank_reach(x)
    np.testing.assert_allclose(geometry.slider_position(reach), x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(geometry.slider_position(-reach), x, rtol=0, atol=1e-12)
    assert np.all(np.diff(reach) < 0)
    for side in (1.0, -1.0):
        assert np.all(geometry.slider_position(side * (reach - 1e-7)) > x)
        assert np.all(geometry.slider_position(side * (reach + 1e-7)) < x)
    l1, l2 = geometry.crank_length, geometry.rod_length
    quarter = float(geometry.crank_reach(np.sqrt(l2**2 - l1**2) + l1 - l2))
    assert quarter == pytest.approx(np.pi / 2, abs=1e-12)
    top = geometry.stroke_top
    edges = geometry.crank_reach([-1e-3, 0.0, top, top + 1e-9])
    np.testing.assert_array_equal(edges[:3], [np.pi, np.pi, 0.0])
    assert edges[3] == -np.inf
