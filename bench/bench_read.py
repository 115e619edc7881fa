"""Benchmark: reading a dataset MCAP, `twin.mcap_chunks`' walk against `mcap`'s reader alone.

Prints, from the same run: wall time of `read_dataset` (the measurement channel, as `crank train`
reads it) and `read_truth` on a dataset of `--seconds` (the default run's 720 s) with the chunk
walk, the same with the library's `iter_messages` alone, and their ratio (the same arrays either
way: tests/test_mcap_chunks.py). `--data FILE` reads a dataset already written instead.

    python bench/bench_read.py [--seconds 720] [--data logs/<run>/dataset.mcap] [--repeats 3]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from timing import median_seconds  # the script's folder is on the path

import twin.mcap_dataset as mcap_dataset
from twin.dataset import GenerationConfig
from twin.generation import generate_file


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=720.0)
    parser.add_argument("--data", type=Path, help="a dataset MCAP to read instead")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = args.data
        if path is None:
            path = Path(tmp) / "dataset.mcap"
            config = GenerationConfig(seconds=args.seconds)
            generate_file(config, out=path, figures=False)
        walk = mcap_dataset.topic_messages
        times = {}
        for name, how in (("walk", walk), ("library", lambda *_: None)):
            mcap_dataset.topic_messages = how
            for channel, read in (
                ("measurement", mcap_dataset.read_dataset),
                ("truth", mcap_dataset.read_truth),
            ):
                times[name, channel] = median_seconds(lambda read=read: read(path), args.repeats)
        mcap_dataset.topic_messages = walk
        samples = len(mcap_dataset.read_dataset(path).t)
    print(f"dataset: {samples} samples ({samples / 500:g} s), median of {args.repeats}")
    for channel in ("measurement", "truth"):
        walked, library = times["walk", channel], times["library", channel]
        print(
            f"read {channel:<11}  walk {walked:6.2f} s   library alone {library:6.2f} s   "
            f"ratio {library / walked:5.2f}x"
        )


if __name__ == "__main__":
    main()
