"""The plan round (twin/plan_data.py, `[plan] episodes`): the planned torque's episodes on fresh
machines come first in a dataset that otherwise is the old one bit for bit, drawn from streams of
their own and reproducible under the seed; the chain trains and solves twice and records both."""

from __future__ import annotations

import json
import tomllib
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from common.errors import ConfigError
from common.jsonio import without_wall_clock
from control.ocp_file import Profile, read_ocp
from control.records import RobustError
from crank import stages
from crank.chain import Hooks, RunConfig, run_chain
from crank.estimate import run_time
from crank.study import run_rows
from crank.sweep import run_sweep
from crank.sweep_spec import leaves_of, node_key
from replay.campaign import tracking_law
from replay.config import ReplayConfig
from tests.test_chain import SHORT
from tests.test_sweep import SPEC as SWEEP_SPEC
from twin.dataset import Dataset
from twin.mcap_dataset import read_dataset, read_run
from twin.physics import SliderCrank
from twin.plan_config import PlanConfig
from twin.plan_data import plan_dataset_file, plan_torques

EPISODES = 6
PLANNED = replace(
    SHORT,  # a 12 s model with a small, uncorrected margin: a robust torque to play
    ocp=replace(SHORT.ocp, profiles=("robust",), tail_check=False),  # the sweep spec's
    replay=replace(SHORT.replay, modes=("open",)),
    heldout_seed=5,
    plan=PlanConfig(episodes=EPISODES),
    figures=False,  # the sweep spec's
)
SPEC = (
    SWEEP_SPEC
    + f"""
[grid]
seed = [0]
heldout_seed = [5]
"ocp.profiles" = [["robust"]]
"replay.modes" = [["open"]]
"plan.episodes" = [{EPISODES}]
"""
)


@pytest.fixture(scope="module")
def planned_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, list[str]]:
    run_dir = tmp_path_factory.mktemp("plan") / "run"
    stages: list[str] = []
    report = run_chain(PLANNED, run_dir, argv=[], hooks=Hooks(on_stage=stages.append))
    return run_dir, report, stages


def test_plan_torques_scale_dither_and_clip() -> None:
    rng = np.random.default_rng(1)
    tau = np.linspace(-1.0, 1.0, 50)
    plain = plan_torques(tau, episodes=200, dither=0.0, limit=10.0, rng=rng)
    scale = plain[:, -1] / tau[-1]
    np.testing.assert_allclose(plain, scale[:, None] * tau[None, :], rtol=1e-12)
    assert scale.min() >= 0.9 and scale.max() <= 1.1 and scale.std() > 0.05
    noise = plan_torques(np.zeros(400), episodes=400, dither=0.3, limit=10.0, rng=rng)
    assert noise.std() == pytest.approx(0.3, rel=0.02)  # 160 000 draws: se 0.2 %
    lag1 = np.mean(noise[:, 1:] * noise[:, :-1]) / noise.var()
    assert lag1 == pytest.approx(0.9, abs=0.02)  # a 10-sample box: 9/10 overlap
    clipped = plan_torques(np.full(20, 5.0), episodes=10, dither=0.3, limit=3.5, rng=rng)
    assert clipped.max() == 3.5


def test_chain_trains_and_solves_twice_and_records_the_round(planned_run) -> None:
    run_dir, report, stages = planned_run
    chain = [
        "generating the dataset",
        "training the PPANN",
        "solving the nominal and robust OCP",
        f"playing the plan on {EPISODES} fresh machines",
        "training again with the plan's episodes",
        "solving the nominal and robust OCP again",
        "replaying on the twin",
    ]
    assert [s for s in stages if s in chain] == chain  # in this order, each once
    for name in ("model.pt", "ocp.json"):
        assert (run_dir / "round-0" / name).is_file() and (run_dir / name).is_file()
    config = json.loads((run_dir / "config.json").read_text())
    assert config["plan"] == {"episodes": EPISODES, "dither": 0.3}
    assert RunConfig.from_dict(config) == PLANNED
    first = read_ocp(run_dir / "round-0" / "ocp.json")
    played = report["plan_round"]["plan"]["played"]
    assert played == {"ocp": "round-0/ocp.json", "profile": "robust"}
    assert "robust" in first.profiles
    cost = report["plan_round"]["first_solve"]["robust cost"]
    assert cost.startswith(f"{first.profiles['robust'].cost:.6g} ")
    # the final model learnt from the merged data: its training saw more samples
    base = read_dataset(run_dir / "dataset.mcap")
    merged = read_dataset(run_dir / "plan.mcap")
    n = PLANNED.ocp.horizon - 1  # the torques of samples 1..N-1 take the plan to sample N
    assert len(merged.t) == len(base.t) + EPISODES * n
    assert report["ppann"]["dataset"]["n_samples"] == len(merged.t)
    text = (run_dir / "report.md").read_text()
    assert "## Plan round (the model and OCP above are its second round)" in text
    assert f"on {EPISODES} fresh machines" in text and "`round-0/`" in text


def test_a_rounds_row_says_whether_its_first_torque_was_refused(planned_run, tmp_path) -> None:
    """crank/study.py run_rows (study.csv, sweep.csv): a chain with the plan round says whether
    its first solve was refused by its own tail's check (crank/stages.py solve_first_round);
    the report's record of it decides, nothing else."""
    run_dir, report, _ = planned_run
    (row,) = run_rows(run_dir, run_dir / "ocp.json")
    assert row["first_round_tail_refused"] is (
        report["plan_round"].get("first_tail_refused") is not None
    )
    refused = report | {"plan_round": report["plan_round"] | {"first_tail_refused": "1.31 %"}}
    (tmp_path / "report.json").write_text(json.dumps(refused))
    stats = report["replay"]["stats"]
    (tmp_path / stats).write_bytes((run_dir / stats).read_bytes())
    (row,) = run_rows(tmp_path, run_dir / "ocp.json")
    assert row["first_round_tail_refused"] is True


def test_plan_data_is_the_dataset_after_the_plan_episodes(planned_run) -> None:
    run_dir, _, _ = planned_run
    base = read_dataset(run_dir / "dataset.mcap")
    merged = read_dataset(run_dir / "plan.mcap")
    profile = read_ocp(run_dir / "round-0" / "ocp.json").profiles["robust"]
    n = len(profile.tau) - 1
    added = EPISODES * n
    for name in ("theta", "omega", "tau", "slider_position"):
        np.testing.assert_array_equal(getattr(merged, name)[added:], getattr(base, name))
    np.testing.assert_array_equal(merged.episode[added:], base.episode + EPISODES)
    np.testing.assert_array_equal(merged.episode[:added], np.repeat(np.arange(EPISODES), n))
    # each added episode starts where the plan starts and is driven by the plan's torque
    first = merged.theta[:added].reshape(EPISODES, n)[:, 0]
    np.testing.assert_allclose(first, profile.theta[0], atol=1e-6)
    tau = merged.tau[:added].reshape(EPISODES, n)
    assert np.all(np.abs(tau - profile.tau[None, :n]) <= 0.1 * np.abs(profile.tau[:n]) + 1.5)
    run = read_run(run_dir / "plan.mcap")
    machines = [e["machine"] for e in run["episodes"] if e.get("plan_episode")]
    trained_on = [e["machine"] for e in read_run(run_dir / "dataset.mcap")["episodes"]]
    assert len(machines) == EPISODES and not any(m in trained_on for m in machines)
    assert run["plan_round"]["streams"]["streams"].keys() == {"plan_machines", "plan_noise"}


Law = Callable[[int, np.ndarray], np.ndarray]
"""A closed-loop law as twin/stepping.py `simulate` takes it."""


def _round_file(
    run_dir: Path, profile: Profile, out: Path, *, seed: int, feedback: Law | None = None
) -> Dataset:
    """The plan round's file of `profile`'s torque on the run's dataset, read back."""
    plan_dataset_file(
        run_dir / "dataset.mcap",
        out,
        tau=profile.tau[:-1],
        theta0=float(profile.theta[0]),
        omega0=float(profile.omega[0]),
        config=PlanConfig(episodes=EPISODES),
        seed=seed,
        physics=SliderCrank(),
        played={},
        feedback=feedback,
    )
    return read_dataset(out)


def test_plan_data_is_reproducible_and_the_seed_changes_it(planned_run, tmp_path: Path) -> None:
    run_dir, _, _ = planned_run
    profile = read_ocp(run_dir / "round-0" / "ocp.json").profiles["robust"]
    made = {
        name: _round_file(run_dir, profile, tmp_path / f"{name}.mcap", seed=seed)
        for name, seed in (("a", 0), ("b", 0), ("c", 1))
    }
    np.testing.assert_array_equal(made["a"].slider_position, made["b"].slider_position)
    np.testing.assert_array_equal(
        made["a"].slider_position, read_dataset(run_dir / "plan.mcap").slider_position
    )
    assert not np.array_equal(made["a"].tau, made["c"].tau)


def test_plan_round_refuses_no_episodes_and_bad_torque(tmp_path: Path, planned_run) -> None:
    run_dir, _, _ = planned_run
    options = dict(theta0=0.0, omega0=0.0, seed=0, physics=SliderCrank(), played={})
    with pytest.raises(ConfigError, match=r"plan\.episodes >= 1"):
        plan_dataset_file(
            run_dir / "dataset.mcap",
            tmp_path / "x.mcap",
            tau=np.zeros(5),
            config=PlanConfig(episodes=0),
            **options,
        )
    with pytest.raises(ConfigError, match="finite sequence"):
        plan_dataset_file(
            run_dir / "dataset.mcap",
            tmp_path / "x.mcap",
            tau=np.array([0.0, np.nan]),
            config=PlanConfig(episodes=2),
            **options,
        )
    assert not (tmp_path / "x.mcap").exists()
    with pytest.raises(ConfigError, match=r"plan\.dither must be in"):
        PlanConfig(episodes=2, dither=-0.1)


def test_estimate_and_sweep_keys_know_the_round() -> None:
    without = RunConfig.for_seed(0, plan={"episodes": 0})
    with_round = RunConfig.for_seed(0, plan={"episodes": 240})
    assert "plan" not in run_time(without)
    times = run_time(with_round)
    assert {"plan", "train_plan", "solve_plan"} <= set(times)
    assert times["train_plan"].low > times["train"].low  # more data, and the baselines
    assert times["total"].low > run_time(without)["total"].low
    for kind in ("data", "model"):
        assert node_key(kind, without) == node_key(kind, with_round)
    assert node_key("solve", without) != node_key("solve", with_round)


def test_a_sweep_leaf_with_the_round_is_the_chain(planned_run, tmp_path: Path) -> None:
    """The sweep runs the round inside its solve step: the leaf checks the same torque of the
    same retrained model on the same held-out machines as the chain."""
    run_dir, _, _ = planned_run
    (tmp_path / "spec.toml").write_text(SPEC)
    (leaf,) = leaves_of(tomllib.loads(SPEC), source="spec")
    assert leaf.config == PLANNED
    sweep = run_sweep(tmp_path / "spec.toml", tmp_path / "out", executor="sequential")
    (row,) = sweep["rows"]
    assert not row.get("error")
    solve = tmp_path / "out" / "solve" / row["solve_key"]
    assert (solve / "round-0" / "ocp.json").is_file() and (solve / "plan.mcap").is_file()
    plans = [without_wall_clock(json.loads((d / "ocp.json").read_text())) for d in (solve, run_dir)]
    assert plans[0]["robust"] == plans[1]["robust"]
    ours, theirs = (
        json.loads((d / "report.json").read_text())
        for d in (tmp_path / "out" / "leaf" / row["leaf_key"], run_dir)
    )
    checked = [without_wall_clock(r["heldout"]) for r in (ours, theirs)]
    assert checked[0].pop("ocp") == str(solve / "ocp.json")
    assert checked[1].pop("ocp") == "ocp.json"
    assert checked[0] == checked[1]
    assert ours["plan_round"]["plan"] == theirs["plan_round"]["plan"]  # paths inside the folder
    assert ours["ppann"]["dataset"]["n_samples"] == theirs["ppann"]["dataset"]["n_samples"]


def test_a_first_round_refused_by_its_tail_check_plays_the_unchecked_torque(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """stages.solve_first_round: a refusal by the own-tail check is solved again without it
    (only the check differs), the refusal kept in the summary; a refusal without the check, one
    before the check (RobustError.tail_checked false), or with the check already off, is the
    solve's own error where no fallback is asked for, and the fallback's solve (the check as
    asked) where one is."""

    calls: list[tuple[bool, tuple[str, ...]]] = []

    def solve(config: RunConfig, model: Path, out: Path, *, hooks: Hooks) -> dict:
        calls.append((config.ocp.tail_check, config.ocp.fallback))
        failed = out / "ocp.failed.json"  # as control/solve.py's solve_file keeps a refusal
        if config.ocp.fallback:  # as solve_file: the refused profiles, the fallback solved
            failed.unlink(missing_ok=True)
            return {"refused": {"robust": "beyond the stroke"}, "fallback": config.ocp.fallback}
        if config.ocp.tail_check:
            failed.write_text('{"margins": "checked"}')
            refusal = RobustError(f"below the height on 1.31 %; the margin history is in {failed}")
            refusal.tail_checked = tail_refuses  # as control/profiles.py marks it
            raise refusal
        if fail_unchecked:
            raise RobustError("beyond the stroke")
        failed.unlink(missing_ok=True)
        return {"refused": {}, "k": config.ocp.k_sigma}

    monkeypatch.setattr(stages, "solve", solve)
    checked = replace(PLANNED, ocp=replace(PLANNED.ocp, tail_check=True, fallback=()))
    fail_unchecked, tail_refuses = False, True
    told: list[str] = []
    solved = stages.solve_first_round(
        checked, tmp_path / "m.pt", tmp_path, hooks=Hooks(on_stage=told.append)
    )
    assert calls == [(True, ()), (False, ())]
    assert len(told) == 1 and "without the check" in told[0]  # the user sees the retry
    kept = tmp_path / stages.TAIL_REFUSED  # the refusal's files survive the retry, named
    assert kept.read_text() == '{"margins": "checked"}'
    assert not (tmp_path / "ocp.failed.json").exists()
    assert solved["tail_refused"] == (
        f"below the height on 1.31 %; the margin history is in {tmp_path.name}/{kept.name}"
    )
    assert solved["k"] == PLANNED.ocp.k_sigma  # nothing but the check changed
    fail_unchecked = True
    with pytest.raises(RobustError, match=r"1\.31 %"):  # the first error, not the retry's
        stages.solve_first_round(checked, tmp_path / "m.pt", tmp_path, hooks=Hooks())
    assert (tmp_path / "ocp.failed.json").read_text() == '{"margins": "checked"}'  # as it names
    assert not kept.exists()
    calls.clear()
    unchecked = replace(PLANNED, ocp=replace(PLANNED.ocp, fallback=()))
    with pytest.raises(RobustError, match="beyond the stroke"):  # the check was off: no retry
        stages.solve_first_round(unchecked, tmp_path / "m.pt", tmp_path, hooks=Hooks())
    assert calls == [(False, ())]

    # a refusal before any tail check (beyond the stroke) would only be met again: no retry
    calls.clear()
    tail_refuses = False
    with pytest.raises(RobustError, match=r"1\.31 %"):
        stages.solve_first_round(checked, tmp_path / "m.pt", tmp_path, hooks=Hooks())
    assert calls == [(True, ())]
    tail_refuses = True

    # a line no open-loop torque holds: refused with and without the check, the fallback solved
    # with the check as asked, its refusals in the summary (the round then plays the nominal)
    for tail_check, tried in ((True, [(True, ()), (False, ())]), (False, [(False, ())])):
        calls.clear()
        told.clear()
        asked = replace(PLANNED, ocp=replace(PLANNED.ocp, tail_check=tail_check))
        assert asked.ocp.fallback == ("robust-fb",)  # the default
        solved = stages.solve_first_round(
            asked, tmp_path / "m.pt", tmp_path, hooks=Hooks(on_stage=told.append)
        )
        assert calls == [*tried, (tail_check, ("robust-fb",))]
        assert solved == {"refused": {"robust": "beyond the stroke"}, "fallback": ("robust-fb",)}
        assert "solving the fallback robust-fb" in told[-1] and "nominal" in told[-1]
        assert not (tmp_path / "ocp.failed.json").exists()
        assert not kept.exists()  # the fallback's solve replaced what the refusal kept


def test_data_too_short_for_the_rounds_training_says_it_was_the_round(tmp_path: Path) -> None:
    """The round's training refused for want of early-stopping windows says it was the round's
    and how to train once (a 2 s dataset under 240 episodes of 150 samples failed with the
    data's message alone). Episodes of 0.1 s (50 samples) keep tails of 2 samples, the one cut
    by the validation split (at 967) 1."""
    from ppann.data import DataError

    config = replace(
        PLANNED,
        generation=replace(PLANNED.generation, seconds=2.0, episode_seconds=0.1),
        baselines=False,
    )
    stages.generate(config, tmp_path, hooks=Hooks())
    with pytest.raises(DataError) as error:
        stages.train_again(config, tmp_path / stages.DATASET, tmp_path, hooks=Hooks())
    said = str(error.value)
    assert said.startswith(
        f"training again on the plan round's {EPISODES} episodes and the dataset: samples "
    )
    assert "966..966 (20 ranges of 1 to 2 samples; a window needs 11) hold no window of 10" in said
    assert said.endswith("(--plan-episodes 0 trains once, on the dataset alone)")
    assert not (tmp_path / stages.MODEL).exists()


def test_plan_data_under_a_law_adds_it_to_the_same_draws(planned_run, tmp_path: Path) -> None:
    """`feedback` (bench/closed_round.py): the round's episodes under a tracking law are the open
    round's draws (machines, starts, dither, force) with the law's torque on top: where neither
    torque is at the limit, closed minus open is the law on the measured θ, ω of that sample."""
    run_dir, _, _ = planned_run
    profile = read_ocp(run_dir / "round-0" / "ocp.json").profiles["robust"]
    physics = SliderCrank()
    law = tracking_law(physics, profile, ReplayConfig())
    made = {
        name: _round_file(run_dir, profile, tmp_path / f"{name}.mcap", seed=0, feedback=feedback)
        for name, feedback in (("open", None), ("closed", law))
    }
    np.testing.assert_array_equal(
        made["open"].slider_position, read_dataset(run_dir / "plan.mcap").slider_position
    )
    n = len(profile.tau) - 1
    added = EPISODES * n
    closed, opened = made["closed"], made["open"]
    for name in ("theta", "omega", "tau", "slider_position"):  # the dataset after them, as is
        np.testing.assert_array_equal(getattr(closed, name)[added:], getattr(opened, name)[added:])
    theta = closed.theta[:added].reshape(EPISODES, n)
    omega = closed.omega[:added].reshape(EPISODES, n)
    gains = np.stack([profile.gain_theta, profile.gain_omega], axis=-1)[:n]
    expected = gains[:, 0] * (profile.theta[:n] - theta) + gains[:, 1] * (profile.omega[:n] - omega)
    difference = (closed.tau[:added] - opened.tau[:added]).reshape(EPISODES, n)
    free = (np.abs(closed.tau[:added]) < physics.torque_limit).reshape(EPISODES, n)
    free &= (np.abs(opened.tau[:added]) < physics.torque_limit).reshape(EPISODES, n)
    assert free.mean() > 0.9 and np.abs(expected).max() > 1e-3  # the law acted
    np.testing.assert_allclose(difference[free], expected[free], rtol=0, atol=1e-9)
