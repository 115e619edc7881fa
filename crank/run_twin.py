"""The twin a run folder was made on: the MJCF its config.json names, or a copy given in its place
(`crank compare --mjcf`), checked against the sha256 the run's dataset recorded.

A run folder names its twin by path (config.json's `model_path`, absolute). Moved to another
machine or checkout, the folder stopped at "MJCF not found"; with the file edited since, it
replayed on the edited twin without a word. The dataset's run record carries the sha256 of the
MJCF's bytes (twin/generation.py `provenance`), and that is the identity checked here.

The dataset also carries the MJCF itself (`model.xml`, MuJoCo's own rewrite of it), but it is not
played in the file's place: compiled, it differs from the file's model in the last bits of the
bodies' inertias and orientations (1e-16), enough for a replay not to repeat the run's numbers
to the last digit (2e-10 rad apart after 2000 steps of random torque).
"""

from __future__ import annotations

from pathlib import Path

from common.errors import ConfigError


def made_on(dataset: Path) -> str | None:
    """The sha256 of the MJCF `dataset` was generated on, as its run record keeps it
    (twin/generation.py `provenance`); None where it records none (rig data, older files)."""
    from twin.mcap_dataset import read_run

    return read_run(dataset).get("mjcf_sha256")


def run_twin(
    dataset: Path, model_path: str | Path, *, mjcf: Path | None = None, flag: str = "--mjcf"
) -> Path:
    """The MJCF to replay a run on: `mjcf` if given, else the run's `model_path`, refused unless
    its bytes are those the run's `dataset` was generated from; the errors name `flag` as the
    way to give a copy.

    Raises:
      ConfigError: the file is missing, or it is not the MJCF the dataset was made on.
    """
    from twin.physics import model_sha256

    recorded = made_on(dataset)
    if recorded is None:
        raise ConfigError(f"{dataset} records no MJCF sha256: the twin it was made on is unknown")
    path = Path(mjcf if mjcf is not None else model_path)
    if not path.is_file():
        hint = "" if mjcf is not None else f"; pass {flag} with a copy of that twin"
        raise ConfigError(
            f"MJCF not found: {path} (the twin of {dataset}, sha256 {recorded[:12]}…){hint}"
        )
    if (sha := model_sha256(path)) != recorded:
        raise ConfigError(
            f"{path} is not the twin {dataset} was generated on (sha256 {sha[:12]}…, the "
            f"dataset's {recorded[:12]}…): pass {flag} with a copy of that twin"
        )
    return path
