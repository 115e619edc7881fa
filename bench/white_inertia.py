"""A trained PPANN's checkpoint with its Monte-Carlo's draw of z_J set to another form
(`PPANNConfig.white_inertia`): the same weights, history and data fingerprint, so that a model
trained before the option can be solved and checked with it (training does not depend on it).

    python bench/white_inertia.py --model MODEL.pt --out OUT.pt [--form linear]

Issue 11, session 55 (bench/white_inertia.md).
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from ppann.checkpoint import load, save
from ppann.model_config import WHITE_INERTIA


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--form", choices=WHITE_INERTIA, default="linear")
    args = parser.parse_args()
    model, payload = load(args.model)
    model.config = replace(model.config, white_inertia=args.form)
    written = ("format", "version", "kind", "config", "state_dict")  # save() writes these anew
    extra = {k: v for k, v in payload.items() if k not in written}
    save(args.out, model, kind=payload["kind"], extra=extra)
    print(f"wrote {args.out} (white_inertia {args.form})")


if __name__ == "__main__":
    main()
