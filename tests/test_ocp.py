"""Nominal and robust OCP (eqs. 15, 16): constraints met in the torch model, typed failures,
ocp.json round trip and rejection."""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import torch

from common.streams import stream
from control.config import OCPConfig, OCPConfigError, lower_tail
from control.ocp import NominalOCP, OCPError
from control.ocp_file import OCPFileError, read_ocp
from control.robust import BeyondStrokeError, solve_robust
from control.solve import figure_paths, solve_file
from control.tightening import slider_uncertainty
from ppann.checkpoint import CheckpointError, save
from ppann.heads import FusedHeads
from ppann.model import PPANN, constant_ppann, rollout
from ppann.montecarlo import monte_carlo
from tests.conftest import crank
from twin.geometry import PAPER

SAMPLES = np.array(OCPConfig().constraint_samples) - 1


@pytest.fixture(scope="module")
def model() -> PPANN:
    """Prior J_m = 3e-3, B_m = 0.1, K_m = 1 with z_K = -0.9: the stiffness torque still jumps by
    2 pi K (1 + z_K) = 0.63 N·m where theta crosses 2 pi."""
    return constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))


@pytest.fixture(scope="module")
def ocp(model: PPANN) -> NominalOCP:
    return NominalOCP(model)


def test_one_kinematics_for_numpy_and_casadi_is_the_papers() -> None:
    """x(theta) in CasADi equals the NumPy evaluation of the same code, and the paper's form
    l1 cos(theta) + l2 cos(asin(l1/l2 sin(theta))) + l1 - l2."""
    theta = np.linspace(-7, 7, 301)
    symbol = ca.SX.sym("theta")
    casadi = ca.Function("x", [symbol], [PAPER.slider_position(symbol, lib=ca)])
    via_casadi = np.array([float(casadi(t)) for t in theta])
    np.testing.assert_allclose(via_casadi, PAPER.slider_position(theta), rtol=0, atol=1e-16)
    l1, l2 = 0.05, 0.3
    paper = l1 * np.cos(theta) + l2 * np.cos(np.arcsin(l1 / l2 * np.sin(theta))) + l1 - l2
    np.testing.assert_allclose(PAPER.slider_position(theta), paper, rtol=0, atol=1e-15)


def test_nominal_torque_meets_eq15_in_the_torch_model(model: PPANN, ocp: NominalOCP) -> None:
    solution = ocp.solve()
    c = ocp.config
    assert solution.status == "Solve_Succeeded"
    assert np.all(np.abs(solution.tau) <= c.torque_limit + 1e-9)
    with torch.no_grad():
        states = rollout(
            model,
            torch.tensor([c.theta_start, c.omega_start], dtype=torch.float64),
            torch.from_numpy(solution.tau[:-1]),
        ).numpy()
    assert states.shape == (c.horizon, 2)
    # the trajectory crosses theta = 2 pi, where torch's theta_mod wraps, and still agrees
    assert states[0, 0] < 2 * math.pi < states[-1, 0]
    np.testing.assert_allclose(states, solution.states, rtol=0, atol=1e-6)
    assert abs(states[-1, 0] - 3 * math.pi) <= 1e-6
    assert abs(states[-1, 1]) <= 1e-6
    assert np.all(PAPER.slider_position(states[SAMPLES, 0]) >= 0.08 - 1e-6)
    # the constraint is active: without it the optimum would not dwell near top dead centre
    assert np.any(np.abs(PAPER.slider_position(states[SAMPLES, 0]) - 0.08) < 1e-6)
    # cost as defined in section 3.4.1, recomputed from the torque
    u = solution.tau
    cost = np.sum(u**2) + 1e-4 * np.sum((np.diff(u) / ocp.dt) ** 2)
    assert solution.cost == pytest.approx(cost, rel=1e-9)


def test_robust_torque_keeps_mean_minus_3_sigma(model: PPANN, ocp: NominalOCP) -> None:
    result = solve_robust(model, ocp.config, ocp=ocp)
    heads = FusedHeads(model)
    nominal = slider_uncertainty(heads, result.nominal, ocp.config)
    robust = slider_uncertainty(heads, result.robust, ocp.config)
    # the nominal torque breaks eq. 16 (else the test shows nothing) and the robust one keeps it
    assert np.any(result.nominal.slider[SAMPLES] - 3 * nominal.std[SAMPLES] < 0.08 - 1e-3)
    assert np.all(result.robust.slider[SAMPLES] - 3 * robust.std[SAMPLES] >= 0.08 - 1e-4)
    assert result.robust.cost >= result.nominal.cost
    last = result.iterations[-1]
    np.testing.assert_array_less(np.abs(last.tightening - last.margin), 1e-4)
    # drafts drive the iteration; the result is the last, settled with the torch model's own
    # states (control/aware.py `exact`; a full solve where its crossing moved)
    assert result.robust.status == "Solve_Succeeded"
    assert result.iterations[0].draft
    np.testing.assert_array_equal(result.robust.heights, 0.08 + last.margin)
    # the robust solution is a solution of eq. 15 with the raised heights, in the torch model
    with torch.no_grad():
        states = rollout(
            model,
            torch.tensor([math.pi, 0.0], dtype=torch.float64),
            torch.from_numpy(result.robust.tau[:-1]),
        ).numpy()
    np.testing.assert_allclose(states, result.robust.states, rtol=0, atol=1e-6)


def test_quantile_tightening_keeps_the_monte_carlo_quantile(model: PPANN) -> None:
    """With quantile tightening the robust torque's own Monte-Carlo has at most Φ(−3) of its
    trajectories below the height at each constraint sample (to the margin tolerance)."""
    config = replace(OCPConfig(), tightening="quantile", mc_samples=0)
    result = solve_robust(model, config)
    unc = slider_uncertainty(FusedHeads(model), result.robust, config)
    bands = monte_carlo(
        model,
        result.robust.states[0],
        result.robust.tau[:-1],
        n_samples=config.mc_samples,
        mode=config.mc_mode,
        seed=stream(config.mc_seed, "monte_carlo"),
    )
    slider = PAPER.slider_position(bands.samples[:, :, 0])
    for i, k in enumerate(SAMPLES):
        quantile = np.quantile(slider[:, k], lower_tail(3.0))
        assert quantile >= 0.08 - 1.5e-4
        point = unc.tightening[i] - unc.population[i] - unc.sampling[i]  # plan − quantile
        assert result.robust.slider[k] - point == pytest.approx(quantile, abs=1e-12)
        # the allowance for the Monte-Carlo's error puts the quantile itself above the height
        assert quantile >= 0.08 + unc.sampling[i] - 1.5e-4 and unc.sampling[i] > 0
    assert config.mc_samples == 14816


def test_draft_solve_agrees_with_the_full_solve(ocp: NominalOCP) -> None:
    """A draft (one loose pass, shared derivative functions) started at a full optimum returns
    it; after a jump (primal warm start only) it still meets the raised heights."""
    full = ocp.solve()
    again = ocp.solve(full.heights, warm=full, draft=True)
    np.testing.assert_allclose(again.tau, full.tau, rtol=0, atol=1e-6)
    assert again.cost == pytest.approx(full.cost, rel=1e-8)
    raised = full.heights + np.array([0.004, 0.006])  # beyond DRAFT_JUMP
    jump = ocp.solve(raised, warm=full, draft=True)
    assert jump.turn_passes == 1
    assert np.all(jump.slider[SAMPLES] >= raised - 1e-8)
    assert np.all(np.abs(jump.tau) <= ocp.config.torque_limit + 1e-9)
    assert jump.cost > full.cost
    with pytest.raises(ValueError, match="warm start"):
        ocp.solve(raised, draft=True)


def test_primal_draft_is_not_pushed_off_its_bounds(ocp: NominalOCP) -> None:
    """A draft from the warm start's primal point alone (`multipliers=False`, control/aware.py's
    first solve) starts on that point (PRIMAL_BOUND_PUSH), where a draft after a height jump is
    pushed off its bounds by IPOPT's default: the same torque to the draft tolerance, in fewer
    IPOPT iterations."""
    full = ocp.solve()
    raised = full.heights + np.array([0.004, 0.006])  # beyond DRAFT_JUMP: pushed by default
    pushed = ocp.solve(raised, warm=full, draft=True)
    primal = ocp.solve(raised, warm=full, draft=True, multipliers=False)
    np.testing.assert_allclose(primal.tau, pushed.tau, rtol=0, atol=1e-5)
    assert np.all(primal.slider[SAMPLES] >= raised - 1e-8)
    assert primal.iterations < pushed.iterations


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler here")
def test_compiled_nlp_gives_the_same_solutions(
    model: PPANN, ocp: NominalOCP, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`compiled=True` (the NLP's functions in C): the same full solve and the same draft after a
    jump as CasADi's virtual machine, to 1e-9, the drafts sharing the compiled functions; the
    build leaves nothing in the working folder."""
    monkeypatch.chdir(tmp_path)
    compiled = NominalOCP(model, OCPConfig(compiled=True))
    assert list(tmp_path.iterdir()) == []
    assert (compiled.engine, ocp.engine) == ("compiled", "vm")
    full, reference = compiled.solve(), ocp.solve()
    np.testing.assert_allclose(full.tau, reference.tau, rtol=0, atol=1e-9)
    assert full.iterations == reference.iterations
    raised = full.heights + np.array([0.004, 0.006])
    draft = compiled.solve(raised, warm=full, draft=True)
    np.testing.assert_allclose(
        draft.tau, ocp.solve(raised, warm=reference, draft=True).tau, rtol=0, atol=1e-9
    )


def test_impossible_height_is_a_typed_error(model: PPANN) -> None:
    with pytest.raises(OCPError) as info:
        NominalOCP(model, OCPConfig(height=0.2)).solve()
    error = info.value
    assert "slider position ≥ 0.2 m at sample" in error.constraint
    assert error.violation > 0.09  # the stroke ends at 0.1 m
    assert error.status in str(error) and "\n" not in str(error)


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"horizon": 2}, "horizon"),
        ({"constraint_samples": (50, 150)}, "outside"),
        ({"constraint_samples": (50, 50)}, "distinct"),
        ({"torque_limit": 0.0}, "torque_limit"),
        ({"height": float("nan")}, "height"),
        ({"mc_samples": 1}, "mc_samples"),
        ({"mc_mode": "sometimes"}, "Monte-Carlo mode"),
        ({"fallback": ("open",)}, "fallback must be distinct names among"),
        ({"fallback": ("robust-fb", "robust-fb")}, "fallback must be distinct names among"),
    ],
)
def test_bad_settings(change: dict, match: str) -> None:
    with pytest.raises(OCPConfigError, match=match):
        OCPConfig(**change)


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory, model: PPANN) -> Path:
    folder = tmp_path_factory.mktemp("ocp")
    save(folder / "model.pt", model, kind="ppann", extra={})
    config = OCPConfig(profiles=("robust", "robust-fb"))
    solve_file(folder / "model.pt", folder / "ocp.json", config=config)
    return folder / "ocp.json"


def test_ocp_json_round_trips(solved: Path) -> None:
    raw = json.loads(solved.read_text())
    loaded = read_ocp(solved)
    assert loaded.horizon == 150 and loaded.dt == pytest.approx(1 / 500)
    assert loaded.names == ("nominal", "robust", "robust-fb") and loaded.refused == {}
    for name in loaded.names:
        profile = loaded.profiles[name]
        np.testing.assert_array_equal(profile.tau, raw[name]["tau"])
        np.testing.assert_array_equal(profile.slider_sigma, raw[name]["slider_sigma"])
        assert profile.cost == raw[name]["cost"]
    assert [loaded.profiles[n].loop for n in loaded.names] == ["open", "open", "closed"]
    for name in loaded.robust_names:
        assert loaded.profiles[name].cost >= loaded.nominal.cost
        assert raw["robust_iterations"][-1 if name == "robust-fb" else 0]["profile"] == name
    # the open loop's margins by control/aware.py first (on this model's steep map the bracket
    # then settles them: tests/test_aware.py), the tube's by the bracket (control/robust.py)
    schemes = [(it["profile"], it["scheme"]) for it in raw["robust_iterations"]]
    assert schemes[0] == ("robust", "aware")
    assert {s for p, s in schemes if p == "robust-fb"} == {"bracket"}
    # the tube is sized for the closed loop's spread: a smaller premium than the open loop's
    assert 0 <= loaded.premium("robust-fb") < loaded.premium("robust")
    assert set(raw["timing"]["robust_loop_s"]) == {"robust", "robust-fb"}
    paths = figure_paths(solved, loaded.names)
    assert [p.name for p in paths.values()] == [
        "ocp.nominal.png",
        "ocp.robust.png",
        "ocp.robust-fb.png",
    ]
    assert all(p.stat().st_size > 10_000 for p in paths.values())


def test_each_profile_is_the_one_solved_alone(model: PPANN, solved: Path) -> None:
    """Solving both robust profiles from one nominal plan gives each the torque it has when
    solved alone (solve_robust), to the last bit."""
    loaded = read_ocp(solved)
    for name in loaded.robust_names:
        alone = solve_robust(model, OCPConfig(), profile=name)
        np.testing.assert_array_equal(loaded.profiles[name].tau, alone.robust.tau)
        np.testing.assert_array_equal(loaded.profiles[name].gain_theta, alone.robust_gains[:, 0])


def test_a_refused_profile_leaves_the_other(tmp_path: Path) -> None:
    """On a line whose open-loop spread exceeds the stroke, `robust` is refused with its reason
    and `robust-fb` (the LQR tube) is written alone; asked for alone, `robust` is refused and
    its fallback, that tube, solved; without a fallback it fails the solve and leaves only
    ocp.failed.json."""
    wide = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.2, 0.35, 0.35))
    save(tmp_path / "wide.pt", wide, kind="ppann", extra={})
    config = OCPConfig(confidence=0.0, profiles=("robust", "robust-fb"))
    solve_file(tmp_path / "wide.pt", tmp_path / "ocp.json", config=config)
    loaded = read_ocp(tmp_path / "ocp.json")
    assert loaded.names == ("nominal", "robust-fb")
    # decided at once, with the count of the tightening it was solved with (its own tail,
    # control/tail.py, may have sent it on to the quantile tightening)
    tube = loaded.raw["robust-fb"]
    method = tube["tightening_method"]
    assert tube["mc_samples"] == replace(config, tightening=method, mc_samples=0).mc_samples
    assert tube["tail_checks"][-1]["tightening"] == method
    assert "open loop cannot keep this spread" in loaded.refused["robust"]
    assert loaded.nominal.loop == "closed"  # its bands are of the first profile solved
    assert not (tmp_path / "ocp.robust.png").exists()
    assert loaded.fallback == ()  # a profile asked for was solved
    # asked for alone: the fallback (OCPConfig.fallback), the tube, is solved from the same
    # plan, and is the tube asked for beside it to the last bit
    told: list[str] = []
    config = OCPConfig(confidence=0.0)
    solve_file(tmp_path / "wide.pt", tmp_path / "fell.json", config=config, on_fallback=told.append)
    assert told == ["robust refused: solving the fallback robust-fb"]
    fell = read_ocp(tmp_path / "fell.json")
    assert fell.names == ("nominal", "robust-fb") and fell.fallback == ("robust-fb",)
    assert fell.refused == loaded.refused
    spread = fell.raw["refused_spread"]["robust"]  # the figures the refusal's words give
    assert spread["sample"] in (50, 100) and spread["tightening"] > spread["available"] > 0
    assert (
        f"sample {spread['sample']} ({1e3 * spread['tightening']:.1f} mm" in fell.refused["robust"]
    )
    np.testing.assert_array_equal(fell.profiles["robust-fb"].tau, loaded.profiles["robust-fb"].tau)
    assert fell.raw["config"]["profiles"] == ["robust"]
    # and without one the solve fails, leaving only its failure's file
    alone = OCPConfig(confidence=0.0, fallback=())
    with pytest.raises(BeyondStrokeError):
        solve_file(tmp_path / "wide.pt", tmp_path / "alone.json", config=alone)
    assert not (tmp_path / "alone.json").exists()
    failed = json.loads((tmp_path / "alone.failed.json").read_text())
    assert {it["profile"] for it in failed["robust_iterations"]} == {"robust"}


def _broken(solved: Path, tmp_path: Path, edit) -> Path:
    raw = json.loads(solved.read_text())
    edit(raw)
    path = tmp_path / "broken.json"
    path.write_text(json.dumps(raw))
    return path


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda r: r.pop("robust"), "missing key 'robust'"),
        (lambda r: r.pop("robust-fb"), "missing key 'robust-fb'"),
        (lambda r: r["profiles"].append("robust"), "profiles must be 'nominal' then distinct"),
        (lambda r: r.__setitem__("profiles", ["robust"]), "profiles must be 'nominal' then"),
        (lambda r: r["robust-fb"].__setitem__("loop", "mpc"), "robust-fb.loop must be open or"),
        (lambda r: r.__setitem__("refused", {"robust": 3}), "refused must map profiles to"),
        (lambda r: r.__setitem__("fallback", ["robust-pd"]), "fallback must list robust profiles"),
        (lambda r: r["nominal"].pop("tau"), "missing key 'nominal.tau'"),
        (lambda r: r["robust"]["tau"].pop(), "robust.tau has 149 values, expected 150"),
        (
            lambda r: r["robust"]["slider"].__setitem__(7, float("nan")),
            "non-finite value at index 7",
        ),
        (lambda r: r["nominal"].__setitem__("cost", float("inf")), "nominal.cost must be a finite"),
        (lambda r: r.__setitem__("format", "other"), "not a crank-ocp file"),
    ],
)
def test_malformed_ocp_json_is_rejected(solved: Path, tmp_path: Path, edit, match: str) -> None:
    with pytest.raises(OCPFileError, match=match) as info:
        read_ocp(_broken(solved, tmp_path, edit))
    assert "\n" not in str(info.value)


def test_cli_solve_impossible_request_writes_nothing(solved: Path, tmp_path: Path) -> None:
    out = tmp_path / "ocp.json"
    result = crank(
        "solve", "--model", str(solved.parent / "model.pt"), "--out", str(out), "--height", "0.2"
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: OCP failed: IPOPT status")
    assert "slider position ≥ 0.2 m" in lines[0]
    assert list(tmp_path.iterdir()) == []


def test_cli_solve_writes_ocp_json(solved: Path, tmp_path: Path) -> None:
    out = tmp_path / "out" / "ocp.json"
    result = crank("solve", "--model", str(solved.parent / "model.pt"), "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert "robust cost" in result.stdout
    fresh, reference = read_ocp(out), read_ocp(solved)
    # the same checkpoint and settings give the same torques
    assert fresh.names == ("nominal", "robust")  # the default: the paper's profile alone
    np.testing.assert_allclose(
        fresh.profiles["robust"].tau, reference.profiles["robust"].tau, rtol=0, atol=1e-9
    )


def test_solve_refuses_a_model_trained_at_another_sample_time(model: PPANN, tmp_path: Path) -> None:
    """dt travels in the checkpoint: a model whose data were sampled at 1 kHz but which integrates
    at 2 ms is refused before any solve, and nothing is written."""
    path = tmp_path / "model.pt"
    save(path, model, kind="ppann", extra={"dt": 0.001})
    with pytest.raises(CheckpointError, match=r"trained on samples 0\.001 s apart but integrates"):
        solve_file(path, tmp_path / "ocp.json", config=OCPConfig())
    assert not (tmp_path / "ocp.json").exists()
