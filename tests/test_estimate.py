"""crank.estimate: the time said before a run scales with what the run asks for, and its parts
add up to its total."""

from __future__ import annotations

import math

import pytest

from crank.chain import RunConfig
from crank.estimate import (
    EARLY_EPOCHS,
    GENERATE_PER_SECOND,
    HELDOUT_PER_SAMPLE,
    MPC_STEP,
    PLAN_STEP,
    REPLAY_FIXED,
    REWRITE_PER_SECOND,
    WINDOW_STEP_EPOCH,
    Span,
    describe,
    heldout_time,
    left,
    run_time,
    solve_time,
    train_time,
)
from ppann.train_config import PLAN_FIT_EPOCHS, PLAN_FIT_MIN_EPISODES
from twin import DATASET_SECONDS, PAPER_SECONDS
from twin.physics import SAMPLE_RATE
from twin.plan_config import PlanConfig


def test_stages_add_up_to_the_total() -> None:
    times = run_time(RunConfig(heldout_runs=1000))
    first, rounds = ["generate", "train", "solve"], ["plan", "train_plan", "solve_plan"]
    assert list(times) == [*first, *rounds, "replay", "heldout", "total"]  # the default's round
    parts = [span for name, span in times.items() if name != "total"]
    assert times["total"].low == pytest.approx(sum(s.low for s in parts))
    assert times["total"].high == pytest.approx(sum(s.high for s in parts))
    assert "heldout" not in run_time(RunConfig())
    rest = left(times, ["generate", "train"])  # a resumed run's
    assert list(rest) == ["solve", *rounds, "replay", "heldout", "total"]
    assert rest["total"].high == pytest.approx(
        sum(rest[k].high for k in ("solve", *rounds, "replay", "heldout"))
    )
    one = run_time(RunConfig(heldout_runs=1000, plan=PlanConfig(episodes=0)))
    assert list(one) == [*first, "replay", "heldout", "total"]
    assert "epoch cap" in describe(rest)  # the round's training is still to come
    trained = left(times, ["generate", "train", "solve", "plan", "train_plan"])
    assert "epoch cap" in describe(times) and "epoch cap" not in describe(trained)


def test_default_run_is_the_measured_few_minutes() -> None:
    """The unit costs are session 82's idle `crank run --seed 0 --heldout-runs 0` (458 s: the
    plan round's two trainings and solves, phase 1 stopping at 75 and 93 epochs); the same
    without the round (`--plan-episodes 0`, the baselines beside the PPANN, phase 1 at 75) took
    227 s, measured after the unit costs were set. Earlier runs are no longer the chain's: 959 s
    (session 61, 240 episodes by --config), 396 s for one round (session 21)."""
    times = run_time(RunConfig.for_seed(0, heldout_runs=0))
    assert times["generate"].low == pytest.approx(GENERATE_PER_SECOND * DATASET_SECONDS)
    assert 100 < times["total"].low < 458 < times["total"].high
    one = run_time(RunConfig.for_seed(0, heldout_runs=0, plan={"episodes": 0}))
    assert 100 < one["total"].low < 227 < one["total"].high


def test_each_stage_scales_with_its_request() -> None:
    uncapped = {"epoch_windows": 10**9}
    paper = {"seconds": PAPER_SECONDS}
    base = RunConfig.for_seed(0, generation=paper, train=uncapped, heldout_runs=1000)
    longer = RunConfig.for_seed(
        0, generation={"seconds": 2 * PAPER_SECONDS}, train=uncapped, heldout_runs=1000
    )
    assert run_time(longer)["generate"].low == pytest.approx(2 * run_time(base)["generate"].low)
    assert run_time(longer)["train"].low > 1.9 * (run_time(base)["train"].low - 20)
    # phase 1's epoch capped at epoch_windows: a longer dataset costs its phase 2 alone more
    # (one pass of it here; the residual's mean makes two, below)
    one_pass = {"residual_mean": False}
    capped = RunConfig.for_seed(
        0, generation={"seconds": 2 * PAPER_SECONDS}, train=one_pass, heldout_runs=1000
    )
    single = RunConfig.for_seed(0, generation=paper, train=uncapped | one_pass, heldout_runs=1000)
    assert run_time(capped)["train"].low < 1.2 * run_time(single)["train"].low
    twice = run_time(RunConfig.for_seed(0, heldout_runs=1000))["train"]
    once = run_time(RunConfig.for_seed(0, train=one_pass, heldout_runs=1000))["train"]
    assert 0 < twice.low - once.low == pytest.approx(twice.high - once.high)  # phase 2 again
    base = RunConfig.for_seed(0, heldout_runs=1000)
    more = RunConfig.for_seed(0, replay={"runs": 200}, heldout_runs=2000)
    for stage, fixed in (("replay", REPLAY_FIXED), ("heldout", 0.0)):
        assert run_time(more)[stage].low - fixed == pytest.approx(
            2 * (run_time(base)[stage].low - fixed)
        )
    # the plan round: its episodes' generation, and the dataset read and written again with them
    longer_plan = RunConfig.for_seed(0, plan={"episodes": 480}, heldout_runs=1000)
    generated = run_time(longer_plan)["plan"].low - run_time(base)["plan"].low
    added = (480 - base.plan.episodes) * base.ocp.horizon / SAMPLE_RATE
    assert generated == pytest.approx(GENERATE_PER_SECOND * added)
    bigger = RunConfig.for_seed(0, generation={"seconds": 2 * DATASET_SECONDS}, heldout_runs=1000)
    rewritten = run_time(bigger)["plan"].low - run_time(base)["plan"].low
    assert rewritten == pytest.approx(REWRITE_PER_SECOND * DATASET_SECONDS)
    assert solve_time(horizon=300, mc_samples=1000).low == pytest.approx(
        2 * solve_time(horizon=150, mc_samples=1000).low
    )
    fewer = solve_time(horizon=150, mc_samples=100)
    assert fewer.low < solve_time(horizon=150, mc_samples=1000).low
    # both robust profiles: three profiles replayed, held out in two loops (open and closed)
    both = RunConfig.for_seed(0, ocp={"profiles": ("robust", "robust-fb")}, heldout_runs=1000)
    assert run_time(both)["heldout"].low == pytest.approx(3 * run_time(base)["heldout"].low)
    assert run_time(both)["replay"].low - REPLAY_FIXED == pytest.approx(
        1.5 * (run_time(base)["replay"].low - REPLAY_FIXED)
    )
    assert run_time(both)["solve"].low == pytest.approx(2 * run_time(base)["solve"].low)


def test_the_heldout_check_scales_with_machines_profiles_loops_and_the_mpc() -> None:
    """`crank heldout`'s opening estimate: machines x profiles x loops x samples, and in the mpc
    loop each machine's MPC steps as a campaign's."""
    one = heldout_time(runs=1000, horizon=150, profiles=2)
    assert one.low == one.high == pytest.approx(HELDOUT_PER_SAMPLE * 1000 * 2 * 150)
    wide = heldout_time(runs=3000, horizon=200, profiles=3, modes=("open", "closed"))
    assert wide.low == pytest.approx(one.low * 3 * 1.5 * 2 * 200 / 150)
    mpc = heldout_time(runs=1000, horizon=150, profiles=2, modes=("open", "mpc"), mpc_horizon=20)
    fixed, per = MPC_STEP
    assert mpc.low - 2 * one.low == pytest.approx((fixed + per * 20) * 1000 * 2 * 150)


def test_the_heldout_second_stage_is_the_high_end_only() -> None:
    """A second stage plays only a robust torque its first machines cannot judge: the check's
    low end is one look's, its high end adds the robust profiles' 9000 more, open loop."""
    one = run_time(RunConfig.for_seed(0, heldout_runs=1000))["heldout"]
    staged = run_time(RunConfig.for_seed(0, heldout_runs=1000, heldout_second_stage=9000))
    more = heldout_time(runs=9000, horizon=150, profiles=1)
    assert staged["heldout"].low == one.low
    assert staged["heldout"].high == pytest.approx(one.high + more.high)
    assert more.high == pytest.approx(4.5 * one.high)  # 9000 machines of one profile, 1000 of 2


def test_training_range_runs_from_early_stopping_to_the_epoch_cap() -> None:
    config = RunConfig.for_seed(0, train={"sigma_epochs": 1}, baselines=False)
    span = train_time(config.train, config.generation, baselines=False)
    fixed = train_time(
        RunConfig.for_seed(0, train={"sigma_epochs": 1, "max_epochs": EARLY_EPOCHS}).train,
        config.generation,
        baselines=False,
    )
    assert fixed.low == pytest.approx(fixed.high)  # a cap at the fewest epochs: no range
    phase1 = (span.high - span.low) / (config.train.max_epochs - EARLY_EPOCHS)
    assert span.low == pytest.approx(fixed.low) and phase1 > 0
    # the baselines train beside the PPANN, in less time per epoch: they add nothing
    with_baselines = train_time(config.train, config.generation, baselines=True)
    assert with_baselines.low == pytest.approx(span.low)
    assert sum(WINDOW_STEP_EPOCH[k] for k in ("physics", "blackbox")) < WINDOW_STEP_EPOCH["ppann"]


def test_described_in_one_line() -> None:
    assert str(Span(30, 30)) == "30 s" and str(Span(100, 400)) == "2-7 min"
    assert str(Span(7200, 9000)) == "2.0-2.5 h"
    line = describe(run_time(RunConfig()), times=10)
    assert "\n" not in line and "each run: generate" in line
    assert line.startswith("estimated time on an idle 2-core machine: ")


def test_plan_fit_adds_its_epochs_to_the_rounds_training_only() -> None:
    """`plan_fit`'s continued phase 1 runs where the data holds the plan round's episodes: its
    PLAN_FIT_EPOCHS epochs, each phase 1's plus the episodes' steps at every minibatch."""
    on = RunConfig.for_seed(0, heldout_runs=0)
    off = RunConfig.for_seed(0, train={"plan_fit": False}, heldout_runs=0)
    assert on.train.plan_fit  # the default since session 96
    assert run_time(on)["train"] == run_time(off)["train"]  # the first round has no episodes
    plan_on, plan_off = run_time(on)["train_plan"], run_time(off)["train_plan"]
    extra = plan_on.low - plan_off.low
    assert extra == pytest.approx(plan_on.high - plan_off.high)
    windows = on.generation.n_samples * (1 - on.train.validation_fraction)
    epoch = min(windows, on.train.epoch_windows)
    per_epoch = WINDOW_STEP_EPOCH["ppann"] * epoch * on.train.horizon
    batches = math.ceil(epoch / on.train.batch_size)
    expected = PLAN_FIT_EPOCHS * (per_epoch + PLAN_STEP * batches * on.ocp.horizon)
    assert extra == pytest.approx(expected)
    assert 15 < extra < 60  # 46 s in session 96's run, at about half session 82's pace
    longer = RunConfig.for_seed(0, ocp={"horizon": 300}, heldout_runs=0)
    longer_off = RunConfig.for_seed(
        0, ocp={"horizon": 300}, train={"plan_fit": False}, heldout_runs=0
    )
    grown = run_time(longer)["train_plan"].low - run_time(longer_off)["train_plan"].low
    assert grown - extra == pytest.approx(PLAN_FIT_EPOCHS * PLAN_STEP * batches * 150)
    few = RunConfig.for_seed(0, plan={"episodes": PLAN_FIT_MIN_EPISODES - 1}, heldout_runs=0)
    few_off = RunConfig.for_seed(
        0, plan={"episodes": PLAN_FIT_MIN_EPISODES - 1}, train={"plan_fit": False}, heldout_runs=0
    )
    assert run_time(few)["train_plan"] == run_time(few_off)["train_plan"]  # too few: none
