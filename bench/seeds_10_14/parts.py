"""The σ row's parts per training seed from held-out files: at samples 50 and 100 the slider's σ
ratio (mixed), θ's (mixed, and each part alone: step = white only, machine = machines only) and
the Monte-Carlo mean's lead over the machines' mean θ (mrad).

    python bench/seeds_10_14/parts.py bench/exact_draft/heldout_seed{0..9}.json \
        bench/seeds_10_14/heldout_seed{10..14}.json
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path


def main() -> None:
    for path in sys.argv[1:]:
        samples = json.loads(Path(path).read_text())["profiles"]["robust"]["open"]["samples"]
        seed = re.search(r"seed(\d+)", path)
        out = [f"seed {seed.group(1) if seed else path}:"]
        for k in ("50", "100"):
            theta, slider = samples[k]["theta"], samples[k]["predicted"]["mixed"]
            parts = theta["predicted"]
            lead = 1e3 * (parts["mixed"]["mean"] - theta["observed_mean"])
            out.append(
                f"{k}: slider {slider['ratio']:.3f}, θ {parts['mixed']['ratio']:.3f} (white "
                f"alone {parts['step']['ratio']:.2f}, machines alone "
                f"{parts['machine']['ratio']:.2f}), lead {lead:+.0f} mrad"
            )
        print("  ".join(out))


if __name__ == "__main__":
    main()
