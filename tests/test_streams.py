"""Independent random streams, variability scenarios, and the run configuration that ties them
together."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from common import streams
from common.errors import ConfigError, CrankError
from crank.chain import RunConfig
from ppann.model import constant_ppann
from ppann.montecarlo import _WHITE, monte_carlo
from replay.campaign import draw_machines
from replay.config import ReplayConfig
from twin.dataset import GenerationConfig, generate
from twin.variability import SCENARIOS, Variability


def _episodes(config: GenerationConfig, physics) -> list:
    return generate(config, physics=physics)[2]


def test_replay_and_heldout_machines_are_never_dataset_machines(physics) -> None:
    """The bug this replaces: replay machines 0-8 were exactly the 9 training machines."""
    run = RunConfig.for_seed(0, generation={"seconds": 9.0, "episode_seconds": 1.0})
    data = [e.machine for e in _episodes(run.generation, physics)]
    replay = draw_machines(run.replay, 150).draws
    heldout = draw_machines(replace(run.replay, runs=100), 150, held_out=True).draws
    assert len(data) == 9
    assert not set(data) & set(replay)
    assert not set(data) & set(heldout)
    assert not set(replay) & set(heldout)
    # Nor do the replay start times come from the stream of the dataset's initial angles.
    starts = draw_machines(run.replay, 150).start_times / run.replay.max_start_time
    angles = np.array([e.theta0 for e in _episodes(run.generation, physics)]) / (2 * math.pi)
    assert not np.isin(np.round(starts[:9], 12), np.round(angles, 12)).any()


def test_streams_differ_by_name_and_are_stable() -> None:
    names = list(streams.STREAMS)
    keys = {streams.spawn_key(n) for n in names}
    assert len(keys) == len(names)
    a = streams.rng(5, "replay_machines").random(4)
    b = streams.rng(5, "replay_machines").random(4)
    c = streams.rng(5, "heldout_machines").random(4)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    with pytest.raises(KeyError, match="unknown random stream"):
        streams.stream(0, "replays")
    tree = streams.describe(3)
    assert tree["root_seed"] == 3 and set(tree["streams"]) == set(names)


def test_no_drift_reaches_the_replay() -> None:
    run = RunConfig.for_seed(
        2, generation={"variability": Variability.resolve("paper", drift=False)}
    )
    assert run.generation.variability.drift is False
    assert run.replay.variability.drift is False
    with pytest.raises(ConfigError, match="dataset's variability"):
        replace(run, replay=replace(run.replay, variability=Variability()))


def test_the_dataset_operating_time_reaches_the_replay() -> None:
    """The replays run their machines as long as the dataset's had run, unless told otherwise;
    a run record of before the field (every machine cold) reads back as 0 s."""
    run = RunConfig.for_seed(3, generation={"max_start_time": 5.0})
    assert run.replay.max_start_time == 5.0
    told = RunConfig.for_seed(3, generation={"max_start_time": 5.0}, replay={"max_start_time": 9})
    assert told.replay.max_start_time == 9.0
    old = json.loads(json.dumps(RunConfig.for_seed(3).as_dict()))
    del old["generation"]["max_start_time"]
    assert RunConfig.from_dict(old).generation.max_start_time == 0.0


def test_changing_the_replay_seed_changes_nothing_upstream(physics) -> None:
    base = RunConfig.for_seed(4, generation={"seconds": 2.0, "episode_seconds": 1.0})
    other = replace(base, replay=replace(base.replay, seed=99))
    a, b = base.as_dict(), other.as_dict()
    for stage in ("generation", "train", "ocp"):
        assert a[stage] == b[stage]
    da = generate(base.generation, physics=physics)[0]
    db = generate(other.generation, physics=physics)[0]
    assert np.array_equal(da.theta, db.theta)
    ma, mb = draw_machines(base.replay, 10), draw_machines(other.replay, 10)
    assert ma.draws != mb.draws


def test_every_stage_takes_the_root_seed() -> None:
    run = RunConfig.for_seed(7)
    assert run.generation.seed == run.train.seed == run.ocp.mc_seed == run.replay.seed == 7
    with pytest.raises(ConfigError, match="root seed"):
        replace(run, train=replace(run.train, seed=8))
    moved = run.with_seed(11)
    assert moved.generation.seed == moved.ocp.mc_seed == 11
    recorded = json.loads(json.dumps(run.as_dict()))
    assert recorded["streams"]["root_seed"] == 7


def test_scenarios_widen_friction_and_damping_only() -> None:
    paper = Variability.scenario("paper")
    assert paper == Variability()
    for name, spread in (("line-15", 0.15), ("line-30", 0.30)):
        line = Variability.scenario(name)
        assert line.name == name
        for p in (line.motor_damping, line.slider_frictionloss):
            assert p.low == pytest.approx(p.nominal * (1 - spread))
            assert p.high == pytest.approx(p.nominal * (1 + spread))
        assert line.backlash_width == paper.backlash_width
        assert line.warmup_drop == paper.warmup_drop
        assert Variability.from_dict(line.as_dict()) == line
    assert set(SCENARIOS) == {"paper", "line-15", "line-30"}


def test_range_file(tmp_path) -> None:
    path = tmp_path / "wide.toml"
    path.write_text('base = "line-15"\n[motor_damping]\nlow = 0.05\nhigh = 0.11\n')
    v = Variability.from_file(path)
    assert v.name == "wide" and (v.motor_damping.low, v.motor_damping.high) == (0.05, 0.11)
    assert v.slider_damping == Variability.scenario("line-15").slider_damping
    assert Variability.resolve(str(path)) == v


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[motor_damping]\nlow = 0.1\nhigh = 0.05\n", "low 0.1 > high 0.05"),
        ("[motor_damping]\nlow = nan\nhigh = 0.09\n", "finite number"),
        ("[motor_damping]\nlow = 0.07\nhigh = inf\n", "finite number"),
        ("[motor_damping]\nmiddle = 0.07\n", "table of low, high"),
        ("[gravity]\nlow = 1\nhigh = 2\n", "unknown variability key"),
        ('base = "line-99"\n', "unknown variability scenario"),
        ("[motor_damping\n", "cannot read variability file"),
    ],
)
def test_bad_range_files(tmp_path, text: str, match: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(CrankError, match=match):
        Variability.from_file(path)


def test_unknown_scenario_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match="unknown variability scenario 'line-20'"):
        Variability.resolve("line-20")


def test_replay_config_rejects_bad_counts() -> None:
    with pytest.raises(CrankError, match="runs must be an integer"):
        ReplayConfig(runs=10**12)
    with pytest.raises(CrankError, match="seed must be an integer"):
        ReplayConfig(seed=-1)


def test_kept_draws_are_the_fresh_draws_bit_for_bit() -> None:
    """PrefixDraws gives what a fresh generator draws, for fewer rows after more and more after
    fewer, read-only, and forgets the key used longest ago."""
    sequence = streams.stream(5, "monte_carlo")

    def fresh(rows: int) -> np.ndarray:
        return np.random.default_rng(sequence).standard_normal((rows, 7, 3))

    kept = streams.PrefixDraws(size=2)
    key = (streams.sequence_key(sequence), 7)
    for rows in (40, 99, 12, 99, 250, 3):
        got = kept.get(key, rows, fresh)
        assert np.array_equal(got, fresh(rows))
        assert not got.flags.writeable
    made = []
    kept.get(("other", 1), 5, lambda rows: made.append(rows) or np.zeros(rows))
    kept.get(("third", 1), 5, lambda rows: np.zeros(rows))
    kept.get(key, 3, lambda rows: made.append(rows) or fresh(rows))  # forgotten: drawn again
    assert made == [5, 3]


def test_the_monte_carlo_with_kept_draws_equals_a_fresh_one() -> None:
    """The robust loop's drafts (99 steps) after its full solve (249) and the other way round
    reuse the white draws and equal a Monte-Carlo whose draws were just made."""
    model = constant_ppann(z_mean=(0.0, 0.0, -0.9), z_sigma=(0.03, 0.05, 0.05))
    tau = np.linspace(-1, 2, 249)
    runs = {}
    for steps in (249, 99, 249):
        _WHITE._kept.clear()
        cold = monte_carlo(model, [0.3, 0.0], tau[:steps], n_samples=50, mode="mixed", seed=8)
        warm = monte_carlo(model, [0.3, 0.0], tau[:steps], n_samples=50, mode="mixed", seed=8)
        assert np.array_equal(cold.samples, warm.samples)
        runs[steps] = cold.samples
    short = monte_carlo(model, [0.3, 0.0], tau[:99], n_samples=50, mode="mixed", seed=8)
    assert np.array_equal(short.samples, runs[99])
    assert np.array_equal(runs[249][:, :100], runs[99])
