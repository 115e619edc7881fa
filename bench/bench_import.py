"""Benchmark: `crank import` of a 90 s, 1 kHz rig CSV against reading the same file with the
`csv` module alone.

The CSV is the twin's 90 s dataset as a 1 kHz rig would log it (tests/test_rig_import.py: ms,
deg, rpm, mm, the torque's sign flipped; 89 991 rows, 6 columns). Prints, from the same run
(medians of --repeats): the import (read, checks, unit conversion, resampling to 500 Hz, the
dataset MCAP written), the csv module reading every row into floats, and their ratio
(target <= 2); then the import's parts.

    python bench/bench_import.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

from timing import median_seconds  # the script's folder is on the path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.test_rig_import import MAP, UNITS, rig_table, write_csv
from twin.dataset import GenerationConfig
from twin.generation import generate_file
from twin.mcap_dataset import read_dataset
from twin.physics import MODEL_PATH, SliderCrank, load_model
from twin.rig_import import ImportSpec, import_table, read_table, resample


def _csv_alone(path: Path) -> int:
    with path.open(newline="") as f:
        reader = csv.reader(f)
        next(reader)
        rows = [[float(v) for v in row] for row in reader]
    return len(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    spec = ImportSpec.parse(columns=MAP, units=UNITS, flip="tau")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        generate_file(GenerationConfig(seconds=90.0), out=folder / "twin.mcap", figures=False)
        table = write_csv(folder / "rig.csv", rig_table(read_dataset(folder / "twin.mcap")))
        rows = _csv_alone(table)
        n = iter(range(10**6))

        def one_import() -> None:
            import_table(table, folder / f"rig{next(n)}.mcap", spec=spec)

        imported = median_seconds(one_import, args.repeats)
        alone = median_seconds(lambda: _csv_alone(table), args.repeats)
        read = median_seconds(lambda: read_table(table, spec), args.repeats)
        columns = read_table(table, spec)
        geometry = SliderCrank(load_model(MODEL_PATH)[0]).geometry
        converted = median_seconds(
            lambda: resample(columns, spec, geometry=geometry, source="rig"), args.repeats
        )
    print(f"crank import of a 90 s 1 kHz CSV ({rows} rows, 6 columns), medians of {args.repeats}:")
    print(f"  import (read, check, resample to 500 Hz, write MCAP): {imported:.3f} s")
    print(f"  csv module alone, every row to floats:                {alone:.3f} s")
    print(f"  ratio (target <= 2): {imported / alone:.2f}")
    print(
        f"  parts: read {read:.3f} s, checks and resampling {converted:.3f} s, "
        f"MCAP and the rest {imported - read - converted:.3f} s"
    )


if __name__ == "__main__":
    main()
