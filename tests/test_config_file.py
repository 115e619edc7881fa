"""One config file for the chain (crank/config_file.py): the defaults are what `crank run` does,
they round-trip through TOML, a file's keys and types are checked, flags override the file."""

from __future__ import annotations

import inspect
import tomllib
from pathlib import Path

import pytest

from common.errors import CrankError
from crank.chain import RunConfig
from crank.cli_chain import FLAG_KEYS, STUDY_SETTINGS, flag_values, run_command, study_command
from crank.config_file import build, defaults, merge, read_values, to_toml
from crank.console import HELDOUT_RUNS, HELDOUT_SEED, fallback_list, profiles_list
from replay.rates import SECOND_STAGE
from twin import MODEL_PATH


def test_the_defaults_are_what_crank_run_does_and_round_trip() -> None:
    values = defaults()
    assert build(values) == RunConfig.for_seed(
        0,
        heldout_runs=HELDOUT_RUNS,
        heldout_seed=HELDOUT_SEED,
        heldout_second_stage=SECOND_STAGE,
        model_path=str(MODEL_PATH),
    )
    text = to_toml(values, header="a header\nof two lines")
    assert text.startswith("# a header\n# of two lines\n")
    assert merge(defaults(), tomllib.loads(text), source="t") == values
    # every flag of crank run and crank study shows the default its file's defaults hold
    studied = merge(values, STUDY_SETTINGS, source="crank study")
    for command, held in ((run_command, values), (study_command, studied)):
        signature = inspect.signature(command).parameters
        for flag, path in FLAG_KEYS.items():
            if flag not in signature:  # a flag of the other command
                continue
            value = held
            for key in path:
                value = value[key]
            default = signature[flag].default
            if flag in ("profiles", "fallback"):  # given as comma-separated text
                default = (profiles_list if flag == "profiles" else fallback_list)(default)
            assert (str(default) if isinstance(default, Path) else default) == value, flag
    assert set(FLAG_KEYS) <= set(inspect.signature(run_command).parameters) | set(
        inspect.signature(study_command).parameters
    )


def test_a_file_sets_any_stage_and_flags_override_it(tmp_path: Path) -> None:
    path = tmp_path / "crank.toml"
    path.write_text(
        "seed = 4\nfigures = false\n"
        "[generation]\nseconds = 30\nvariability = 'line-15'\ndrift = false\n"
        "[ocp]\nheight = 0.085\nconstraint_samples = [60, 90, 120]\n[train]\nsigma_block = 5\n"
        "[replay]\nmodes = ['closed']\n"
    )
    flags = flag_values({"seconds": 12.0, "fallback": "none"})
    config = build(merge(read_values(path), flags, source="flags"), source=str(path))
    assert config.seed == config.train.seed == config.ocp.mc_seed == config.replay.seed == 4
    assert config.generation.seconds == 12.0  # the flag wins over the file's 30
    assert config.generation.variability.name == "line-15"
    assert not config.generation.variability.drift
    assert config.replay.variability == config.generation.variability
    assert config.ocp.height == 0.085 and config.ocp.constraint_samples == (60, 90, 120)
    assert config.train.sigma_block == 5 and config.replay.modes == ("closed",)
    assert config.ocp.fallback == ()  # --fallback none
    assert config.heldout_runs == HELDOUT_RUNS  # untouched keys keep their defaults
    assert not config.figures and RunConfig.from_dict(config.as_dict()) == config
    assert build(merge(read_values(path), flag_values({"figures": True}), source="f")).figures
    # a lab's few machines: --episodes-per-machine reaches the dataset's generation
    lab = build(merge(read_values(path), flag_values({"episodes_per_machine": 9}), source="f"))
    assert lab.generation.episodes_per_machine == 9 and config.generation.episodes_per_machine == 1
    assert RunConfig.from_dict(lab.as_dict()) == lab


def test_the_replays_operating_time_follows_the_files_dataset(tmp_path: Path) -> None:
    """A file that starts the dataset's machines cold replays on cold machines too, as the
    command line and the library do; a file that sets the replays' own time keeps it."""
    path = tmp_path / "crank.toml"
    path.write_text("[generation]\nmax_start_time = 0\n")
    config = build(read_values(path), source=str(path))
    assert config.generation.max_start_time == config.replay.max_start_time == 0.0
    path.write_text("[generation]\nmax_start_time = 5\n[replay]\nmax_start_time = 30\n")
    config = build(read_values(path), source=str(path))
    assert (config.generation.max_start_time, config.replay.max_start_time) == (5.0, 30.0)
    assert build(defaults()).replay.max_start_time == build(defaults()).generation.max_start_time


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[ocp]\nheigth = 0.08\n", "unknown key 'ocp.heigth'"),
        ("[train]\nseed = 3\n", "unknown key 'train.seed' (every stage uses the top-level seed)"),
        ("[ocp]\nhorizon = '150'\n", 'ocp.horizon must be an integer, got "150"'),
        ("[ocp]\nhorizon = 150.0\n", "ocp.horizon must be an integer, got 150.0"),
        ("[ocp]\nconstraint_samples = [50, 'x']\n", "must be a list of integers"),
        ("baselines = 1\n", "baselines must be true or false, got 1"),
        ("figures = 'no'\n", 'figures must be true or false, got "no"'),
        ("calibration_runs = 1\n", "calibration_runs must be an integer 2..100000, got 1"),
        ("ocp = 3\n", "ocp must be a table, got 3"),
        ("[ocp]\nhorizon = 2\n", "horizon must be >= 3 samples"),
        ("[generation]\nvariability = 'line-99'\n", "unknown variability scenario 'line-99'"),
        ("[generation]\nseconds = nan\n", "seconds must be a finite number"),
        ("[ocp\n", "is not TOML"),
        ("[train]\nbound_lines = 50\n", "bound_lines must be 0 or at least 200, got 50"),
    ],
)
def test_a_bad_file_is_refused_naming_the_key(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "crank.toml"
    path.write_text(text)
    with pytest.raises(CrankError) as caught:
        build(read_values(path), source=str(path))
    assert match in str(caught.value) and str(path) in str(caught.value)
