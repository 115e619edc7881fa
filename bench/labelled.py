"""The figure scripts' inputs: `LABEL=FILE` arguments, each a label and a JSON file."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def labelled_json(items: list[str], *, script: str) -> list[tuple[str, Path, Any]]:
    """(label, path, the file's JSON) for each `LABEL=FILE` of `items`, in their order.

    Raises:
      SystemExit: an item without `=FILE`, in one line naming `script`.
    """
    runs = []
    for item in items:
        label, _, name = item.partition("=")
        if not name:
            raise SystemExit(f"{script}: expected LABEL=FILE, got {item!r}")
        runs.append((label, Path(name), json.loads(Path(name).read_text())))
    return runs


def figure_parser(doc: str, *, inputs: str) -> argparse.ArgumentParser:
    """The figure scripts' command line: `--out` (the PNG) and the `LABEL=FILE` arguments `runs`
    (`inputs` names the file each label stands for, for the help); a script may add its own."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("runs", nargs="+", help=f"LABEL={inputs}")
    return parser
