"""Several episodes of one machine (a lab's few machines, each run several times): the machine
model's likelihood gives them one offset, a line of M machines counts as M machines' evidence
whatever the number of episodes, and the twin generates and records such datasets."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from common.errors import ConfigError
from ppann.machine import EpisodeTerms, marginal_nll
from ppann.model import PPANNConfig
from ppann.train import History, sigma_data
from tests.test_machine import _machines_dataset, _phase_two, dense_nll
from twin.dataset import Dataset, GenerationConfig, episode_machines, generate
from twin.generation import generate_file
from twin.mcap_dataset import read_dataset
from twin.variability import Variability


def test_a_machines_episodes_share_one_offset_in_the_likelihood() -> None:
    """Four episodes, the first two and the last two one machine's: the Woodbury NLL equals the
    dense Gaussian log-likelihood whose covariance couples every sample of a machine, across its
    episodes (diag(s²) + D Σ Dᵀ over the machine's samples); blocks still end with each episode."""
    rng = np.random.default_rng(7)
    lengths = [10, 10, 12, 8]
    n = sum(lengths)
    residual = torch.from_numpy(rng.normal(size=n))
    derivative = torch.from_numpy(rng.normal(size=(n, 3)))
    design = torch.from_numpy(rng.normal(size=(n, 3)))
    sigma = torch.from_numpy(rng.uniform(0.2, 1.0, size=(n, 3)))
    spread = torch.tensor([0.3, 0.1, 0.5], dtype=torch.float64)
    episode = torch.from_numpy(np.repeat(np.arange(4), lengths))
    machine = torch.from_numpy(np.repeat([0, 0, 1, 1], lengths))
    terms = EpisodeTerms.build(residual, derivative, design, episode, machine=machine)
    total = dense_nll(residual, derivative, design, sigma, spread, machine)
    assert float(marginal_nll(terms, sigma, spread)) == pytest.approx(total / n, rel=1e-10)
    # each episode its own machine: the likelihood of four independent offsets, which differs
    alone = EpisodeTerms.build(residual, derivative, design, episode)
    assert torch.equal(
        marginal_nll(alone, sigma, spread),
        marginal_nll(
            EpisodeTerms.build(residual, derivative, design, episode, machine=episode),
            sigma,
            spread,
        ),
    )
    assert abs(float(marginal_nll(alone, sigma, spread)) - total / n) > 1e-3
    blocks = EpisodeTerms.build(
        residual, derivative, design, episode, machine=machine, block_length=4
    )
    # 10 = 4+4+2 | 10 = 4+4+2 | 12 = 4+4+4 | 8 = 4+4: no block crosses an episode's end
    assert blocks.machine.tolist() == [0] * 6 + [1] * 5
    starts = np.flatnonzero(np.diff(blocks.block.numpy(), prepend=-1))
    assert starts.tolist() == [0, 4, 8, 10, 14, 18, 20, 24, 28, 32, 36]


@pytest.fixture(scope="module")
def runs_line():
    """Phase 2 on a synthetic line of 12 machines, each run 4 times (inertia log-spread 0.15),
    read as the run record says (grouped) and as if each episode were a machine."""
    dataset, truth_model, eta = _machines_dataset(
        episodes=48, seconds=1.0, spread=0.15, seed=11, runs=4
    )
    fitted = {}
    for name, data in (("grouped", dataset), ("episodes", Dataset(**{**vars(dataset), "run": {}}))):
        torch.manual_seed(0)
        history = History()
        model, split = _phase_two(truth_model, data, PPANNConfig(sigma_hidden=4), history=history)
        fitted[name] = (model, history)
    return fitted, eta, split, dataset


def test_the_line_is_as_many_machines_as_it_has_not_as_many_episodes(runs_line) -> None:
    """Grouped, the inertia's machine σ is within 20 % of the 12 drawn machines' sample σ and the
    line's mean log-factor has the textbook standard error s / sqrt(M) of M directly observed
    machines; read as 48 machines the same data claim s / sqrt(E), twice as sure."""
    fitted, eta, split, dataset = runs_line
    _, _, _, _, episode, machine = sigma_data(dataset, split)
    machines, episodes = int(machine.max()) + 1, int(episode.max()) + 1
    assert (machines, episodes) == (12, 46)  # the validation split takes the last two episodes
    grouped, history = fitted["grouped"]
    assert history.spread_data == {"machines": machines, "episodes": episodes}
    assert len(history.machine_offsets) == machines
    drawn = float(np.std(eta, ddof=1))
    s = grouped.machine_sigma[0].item()
    print(f"drawn {drawn:.4f}, fitted {grouped.machine_sigma.tolist()}")
    assert s == pytest.approx(drawn, rel=0.2)
    se = math.sqrt(grouped.common_covariance[0, 0].item())
    assert se == pytest.approx(s / math.sqrt(machines), rel=0.1)
    alone, alone_history = fitted["episodes"]
    assert alone_history.spread_data == {"machines": episodes, "episodes": episodes}
    s_alone = alone.machine_sigma[0].item()
    se_alone = math.sqrt(alone.common_covariance[0, 0].item())
    assert se_alone == pytest.approx(s_alone / math.sqrt(episodes), rel=0.1)
    assert se / se_alone > 1.7


def test_the_twin_plays_each_machine_several_times() -> None:
    """episodes_per_machine 3: episodes 3m..3m+2 are one machine, machine m's draw the one a
    dataset of fresh machines gives its episode m; every other stream (state, torque, noise,
    warm-up) the fresh dataset's; the file records the machine ids and reads back grouped."""
    short = {"seconds": 1.2, "episode_seconds": 0.2, "seed": 4, "variability": Variability()}
    fresh_data, _, fresh = generate(GenerationConfig(**short))
    runs_data, _, runs = generate(GenerationConfig(**short, episodes_per_machine=3))
    assert [e.machine_id for e in runs] == [0, 0, 0, 1, 1, 1]
    assert [e.machine_id for e in fresh] == [None] * 6
    for e in runs:
        assert e.machine == fresh[e.index // 3].machine
        assert (e.theta0, e.start_time) == (fresh[e.index].theta0, fresh[e.index].start_time)
    assert runs[1].machine != fresh[1].machine
    assert np.array_equal(runs_data.tau, fresh_data.tau)
    assert not np.array_equal(runs_data.theta, fresh_data.theta)
    assert np.array_equal(episode_machines(fresh_data), fresh_data.episode)  # no run record
    for bad in (0, True, 1.5):
        with pytest.raises(ValueError, match="episodes_per_machine must be an integer >= 1"):
            GenerationConfig(episodes_per_machine=bad)


def test_a_dataset_file_records_its_machines(tmp_path) -> None:
    out = tmp_path / "runs.mcap"
    config = GenerationConfig(seconds=0.8, episode_seconds=0.1, episodes_per_machine=4)
    summary = generate_file(config, out=out, figures=False)
    assert (summary["episodes"], summary["machines"]) == (8, 2)
    data = read_dataset(out)
    assert [e.get("machine_id") for e in data.run["episodes"]] == [0] * 4 + [1] * 4
    assert data.run["config"]["episodes_per_machine"] == 4
    assert np.array_equal(episode_machines(data), np.repeat([0, 1], 200))
    # episodes given no id are machines of their own, numbered in order of appearance
    mixed = Dataset(
        **{
            **vars(data),
            "run": {"episodes": [{"index": 1, "machine_id": "a"}, {"index": 5, "machine_id": "a"}]},
        }
    )
    expected = [0, 1, 2, 3, 4, 1, 5, 6]
    assert np.array_equal(episode_machines(mixed), np.repeat(expected, 50))


def test_a_labs_plan_round_plays_its_own_machines_again(tmp_path) -> None:
    """On a dataset that names its machines (a lab's), the plan round's episodes are those
    machines again, in turn, each with its recorded draw and id: phase 2 still sees the lab's two
    machines; a dataset of fresh machines gets fresh ones (twin/plan_data.py)."""
    from twin.physics import SliderCrank
    from twin.plan_config import PlanConfig
    from twin.plan_data import lab_machines, plan_dataset_file

    def round_on(config: GenerationConfig, name: str) -> tuple[Dataset, dict]:
        base = tmp_path / f"{name}.mcap"
        generate_file(config, out=base, figures=False)
        summary = plan_dataset_file(
            base,
            tmp_path / f"{name}.plan.mcap",
            tau=np.full(30, 1.0),
            theta0=0.5,
            omega0=0.0,
            config=PlanConfig(episodes=3),
            seed=0,
            physics=SliderCrank(),
            played={},
        )
        return read_dataset(tmp_path / f"{name}.plan.mcap"), summary

    short = {"seconds": 0.8, "episode_seconds": 0.1}
    merged, summary = round_on(GenerationConfig(**short, episodes_per_machine=4), "lab")
    expected = np.concatenate([np.repeat([0, 1, 0], 30), np.repeat([0, 1], 200)])
    assert np.array_equal(episode_machines(merged), expected)
    episodes = merged.run["episodes"]
    assert [e["machine_id"] for e in episodes[:3]] == [0, 1, 0]
    own = {e["machine_id"]: e["machine"] for e in episodes[3:]}
    assert [e["machine"] for e in episodes[:3]] == [own[0], own[1], own[0]]
    assert own[0] != own[1] and summary["machines"] == 2 and not summary["fresh_machines"]
    assert [label for label, _ in lab_machines(merged.run)] == [0, 1]
    fresh, summary = round_on(GenerationConfig(**short), "fresh")
    assert np.array_equal(episode_machines(fresh), np.repeat(np.arange(11), [30] * 3 + [50] * 8))
    plan_draws = [e["machine"] for e in fresh.run["episodes"][:3]]
    assert not any(d in [e["machine"] for e in fresh.run["episodes"][3:]] for d in plan_draws)
    assert summary["machines"] == 3 and summary["fresh_machines"]
    with pytest.raises(ConfigError, match="machine 'A' has no recorded draw"):
        lab_machines({"episodes": [{"index": 0, "machine_id": "A"}]})


@pytest.fixture(scope="module")
def rig_csv(tmp_path_factory: pytest.TempPathFactory):
    """Six 1 s runs of the twin as a 1 kHz rig table (tests/test_rig_import.py), with a machine
    column: runs 0-2 on machine 7, runs 3-5 on machine 9."""
    from tests.test_rig_import import rig_table, write_csv

    folder = tmp_path_factory.mktemp("machines")
    generate_file(
        GenerationConfig(seconds=6.0, episode_seconds=1.0), out=folder / "t.mcap", figures=False
    )
    table = rig_table(read_dataset(folder / "t.mcap"))
    table["unit"] = np.where(table["run"] <= 2, 7, 9)
    return folder, table, write_csv


RIG_MAP = "t=time_ms,theta=enc_deg,omega=speed_rpm,tau=cmd,slider_position=x_mm"
RIG_UNITS = "t=ms,theta=deg,omega=rpm,slider_position=mm"


def test_a_rig_tables_machine_column_groups_its_runs(rig_csv) -> None:
    """With the run and machine columns: six episodes, ids 7, 7, 7, 9, 9, 9, two machines. With
    the machine column alone the three runs of a machine join (no gap between them) but the
    change of machine starts an episode: two episodes, two machines."""
    from twin.rig_import import ImportSpec, import_table

    folder, table, write_csv = rig_csv
    path = write_csv(folder / "rig.csv", table)
    for columns, episodes in ((",episode=run,machine=unit", 6), (",machine=unit", 2)):
        spec = ImportSpec.parse(columns=RIG_MAP + columns, units=RIG_UNITS, flip="tau")
        run = import_table(path, folder / "rig.mcap", spec=spec)
        ids = [e.get("machine_id") for e in run["episodes"]]
        assert ids == [7] * (episodes // 2) + [9] * (episodes // 2)
        assert (run["summary"]["episodes"], run["summary"]["machines"]) == (episodes, 2)
        data = read_dataset(folder / "rig.mcap")
        assert np.array_equal(episode_machines(data), data.episode >= episodes // 2)
    bad = write_csv(folder / "bad.csv", table | {"unit": table["unit"] + 0.5})
    spec = ImportSpec.parse(columns=RIG_MAP + ",machine=unit", units=RIG_UNITS, flip="tau")
    with pytest.raises(ValueError, match="the machine column holds non-integers"):
        import_table(bad, folder / "bad.mcap", spec=spec)
    with pytest.raises(ValueError, match="the machine column has no sign"):
        ImportSpec.parse(columns=RIG_MAP + ",machine=unit", flip="tau,machine")
    assert not (folder / "bad.mcap").exists()


def test_files_named_for_their_machines(rig_csv) -> None:
    """A file per run and machines A, A, B: the first two files' episodes are one machine's."""
    from twin.rig_import import ImportSpec, import_table

    folder, table, write_csv = rig_csv
    files = []
    for run in (0, 1, 2):
        rows = table["run"] == run
        files.append(write_csv(folder / f"r{run}.csv", {k: v[rows] for k, v in table.items()}))
    spec = ImportSpec.parse(columns=RIG_MAP, units=RIG_UNITS, flip="tau")
    run = import_table(files, folder / "files.mcap", spec=spec, machines=["A", "A", "B"])
    assert [e["machine_id"] for e in run["episodes"]] == ["A", "A", "B"]
    data = read_dataset(folder / "files.mcap")
    assert np.array_equal(episode_machines(data), data.episode == 2)
