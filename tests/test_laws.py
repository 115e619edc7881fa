"""replay/laws.py: a replay's band and predicted k·σ are the PPANN's under the law it played.

On a plan solved on a known PPANN: the solve's Monte-Carlo of each profile's own law, re-run
from ocp.json, is the file's σ bit for bit; a replay of another law (the fixed PD on an LQR
profile, the MPC on the PD tube) is predicted by that Monte-Carlo under the gains it applied,
and a replay without the PPANN to predict it says so instead of showing the file's σ.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from control.config import PD_GAINS, OCPConfig
from control.ocp_file import OCPFile, read_ocp
from control.solve import solve_file
from control.tightening import slider_uncertainty
from ppann.checkpoint import save
from ppann.heads import FusedHeads
from ppann.model import PPANN, constant_ppann
from replay.campaign import run_campaign
from replay.config import ReplayConfig
from replay.foxglove import plan_rows
from replay.laws import own_gains, played_gains, predicted_sigma, profile_solution
from replay.statistics import campaign_statistics, summary_rows
from tests.conftest import LATE_MPC, crank
from twin.physics import SliderCrank


@pytest.fixture(scope="module")
def model() -> PPANN:
    return constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))


@pytest.fixture(scope="module")
def solved_path(tmp_path_factory: pytest.TempPathFactory, model: PPANN) -> Path:
    folder = tmp_path_factory.mktemp("laws")
    save(folder / "model.pt", model, kind="ppann", extra={})
    config = OCPConfig(profiles=("robust", "robust-fb", "robust-pd"), mc_samples=300)
    solve_file(folder / "model.pt", folder / "ocp.json", config=config)
    return folder / "ocp.json"


@pytest.fixture(scope="module")
def solved(solved_path: Path) -> OCPFile:
    return read_ocp(solved_path)


def test_the_files_spread_is_its_own_laws_monte_carlo_bit_for_bit(
    solved: OCPFile, model: PPANN
) -> None:
    """Re-run from ocp.json (torque, states, OCP settings and draws), the solve's Monte-Carlo
    gives each profile's open and own-law closed σ of the file to the last bit: the replay's
    prediction of another law is the same computation under other gains."""
    heads = FusedHeads(model)
    assert solved.names == ("nominal", "robust", "robust-fb", "robust-pd")
    for name in solved.names:
        planned = solved.profiles[name]
        solution = profile_solution(planned, solved)
        for gains, sigma in ((None, planned.slider_sigma_open), (own_gains(planned), None)):
            sigma = planned.slider_sigma_closed if sigma is None else sigma
            again = slider_uncertainty(heads, solution, solved.config, gains=gains)
            np.testing.assert_array_equal(again.std, sigma, err_msg=name)
    pd = own_gains(solved.profiles["robust-pd"])
    np.testing.assert_array_equal(pd, np.tile(PD_GAINS, (solved.horizon - 1, 1)))


def _apart(sigma: np.ndarray, other: np.ndarray, ocp: OCPFile) -> float:
    """The largest relative difference of two slider σ at the constraint samples."""
    at = np.array(ocp.config.constraint_samples) - 1
    return float(np.max(np.abs(sigma[at] / other[at] - 1)))


def test_a_replay_is_predicted_under_the_law_it_played(
    physics: SliderCrank, solved: OCPFile, model: PPANN
) -> None:
    """The fixed PD on the LQR tube and the MPC on the PD tube are predicted by the Monte-Carlo
    under the gains applied, not by the file's σ of the profile's own law; the PD tube under its
    PD, and every open loop, by the file's σ. The statistics' k·σ is 3 × that σ."""
    heads = FusedHeads(model)
    pd = ReplayConfig(runs=4, seed=3, modes=("closed",), feedback="pd")
    mpc = ReplayConfig(runs=4, seed=3, modes=("open", "mpc"), mpc=LATE_MPC)
    by_pd = run_campaign(physics, solved, config=pd, model=model)
    by_mpc = run_campaign(physics, solved, config=mpc, model=model)
    stats = campaign_statistics(by_pd, solved, ocp_path="x", timing={})
    for name in solved.names:
        planned = solved.profiles[name]
        solution = profile_solution(planned, solved)
        replay = by_pd.replays[name, "closed"]
        pd_gains = np.tile(PD_GAINS, (solved.horizon - 1, 1))
        expected = slider_uncertainty(heads, solution, solved.config, gains=pd_gains).std
        np.testing.assert_array_equal(replay.predicted_sigma, expected, err_msg=name)
        if name == "robust-pd":  # its own law: the file's closed σ
            np.testing.assert_array_equal(replay.predicted_sigma, planned.slider_sigma_closed)
        else:  # an LQR profile under the PD: not the file's closed σ
            assert _apart(expected, planned.slider_sigma_closed, solved) > 0.2
        for sample, entry in stats["profiles"][name]["closed"]["constraint"].items():
            assert entry["predicted_k_sigma"] == 3 * expected[int(sample) - 1]
        np.testing.assert_array_equal(
            by_mpc.replays[name, "open"].predicted_sigma, planned.slider_sigma_open
        )
        under_mpc = by_mpc.replays[name, "mpc"]
        gains = played_gains(planned, "mpc", mpc, mpc_gains=under_mpc.mpc.gains)
        np.testing.assert_array_equal(gains, under_mpc.mpc.gains)
        lqr = slider_uncertainty(heads, solution, solved.config, gains=gains).std
        np.testing.assert_array_equal(under_mpc.predicted_sigma, lqr, err_msg=name)
    tube = solved.profiles["robust-pd"]  # the MPC is not the PD the tube was sized for
    assert (
        _apart(by_mpc.replays["robust-pd", "mpc"].predicted_sigma, tube.slider_sigma_closed, solved)
        > 0.2
    )


def test_a_law_the_replay_cannot_predict_has_no_band(physics: SliderCrank, solved: OCPFile) -> None:
    """Without the PPANN, an LQR profile under the fixed PD has no prediction: null in the
    statistics, a dash in the table, no band in the Foxglove rows; its own law still has the
    file's."""
    config = ReplayConfig(runs=3, seed=3, modes=("closed",), feedback="pd")
    campaign = run_campaign(physics, solved, config=config)
    stats = campaign_statistics(campaign, solved, ocp_path="x", timing={})
    assert campaign.replays["robust-fb", "closed"].predicted_sigma is None
    np.testing.assert_array_equal(
        campaign.replays["robust-pd", "closed"].predicted_sigma,
        solved.profiles["robust-pd"].slider_sigma_closed,
    )
    rows = {r["profile"]: r for r in summary_rows(stats)}
    key = "3σ@100 obs/pred mm"
    assert rows["robust-fb"][key].endswith("/—") and not rows["robust-pd"][key].endswith("/—")
    entry = stats["profiles"]["robust-fb"]["closed"]["constraint"]["100"]
    assert entry["predicted_k_sigma"] is None and entry["observed_k_sigma"] > 0
    assert set(plan_rows(solved, "robust-fb", None)[0]) == {"planned", "height"}
    with_band = plan_rows(solved, "robust-pd", solved.profiles["robust-pd"].slider_sigma_closed)
    assert set(with_band[0]) == {"planned", "lower", "upper", "height"}


def test_without_a_model_only_the_own_law_is_predicted(solved: OCPFile) -> None:
    planned = solved.profiles["robust-fb"]
    assert predicted_sigma(solved, "robust-fb", None, heads=None) is planned.slider_sigma_open
    own = own_gains(planned)
    assert predicted_sigma(solved, "robust-fb", own, heads=None) is planned.slider_sigma_closed
    assert predicted_sigma(solved, "robust-fb", 0.5 * own, heads=None) is None
    with pytest.raises(ValueError, match="mpc_gains"):
        played_gains(planned, "mpc", ReplayConfig())


def test_crank_replay_predicts_the_pd_with_the_plans_checkpoint(
    tmp_path: Path, solved_path: Path
) -> None:
    """`crank replay --feedback pd` predicts the PD on the LQR profiles with the checkpoint
    ocp.json names; where that file is gone, those rows have no prediction, the terminal says
    which and why, and the replay still runs (the PD tube keeps the file's)."""
    moved = tmp_path / "moved"
    moved.mkdir()
    (moved / "ocp.json").write_bytes(solved_path.read_bytes())  # its model.pt stays behind
    for ocp_path, predicted in ((solved_path, True), (moved / "ocp.json", False)):
        out = tmp_path / f"{predicted}.mcap"
        args = ("--ocp", str(ocp_path), "--out", str(out), "--runs", "3", "--seed", "3")
        done = crank("replay", *args, "--modes", "closed", "--feedback", "pd")
        assert done.returncode == 0, done.stderr
        assert ("—: no prediction for nominal closed" in done.stdout) != predicted
        stats = json.loads(out.with_suffix(".stats.json").read_text())
        entry = stats["profiles"]["robust-fb"]["closed"]["constraint"]["100"]
        assert (entry["predicted_k_sigma"] is not None) == predicted
        own = stats["profiles"]["robust-pd"]["closed"]["constraint"]["100"]["predicted_k_sigma"]
        assert own == 3 * read_ocp(ocp_path).profiles["robust-pd"].slider_sigma_closed[99]
