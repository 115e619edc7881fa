"""Counter-based standard normals: sample i's normals at step k are a function of (key, i, k)
alone, so the C kernel (ppann/kernel.py) generates them where it uses them, on any thread and in
any block, and NumPy gives the same numbers (to the last bits of log, sin and cos) without
drawing them in order.

Why: the torque's own tail check (control/tail.py) draws 20 000 trajectories, four normals per
trajectory and step; drawn by NumPy's generator (~10 ns a normal, 8 million at 100 steps) and
handed to the kernel as arrays (copied per block), that was ~0.15-0.2 s of a ~0.5 s check,
about four nominal solves (docs/history.md); generated here the check takes ~0.07 s.

The generator: sample i has its own SplitMix64 stream, seeded with SplitMix64's output function
on key + golden * (i + 1) (the sample's seed); at step k its outputs 2 k + 1 and 2 k + 2 (the
output function on seed + golden * (2 k + 1 + pair), pair 0 or 1), each split into two 32-bit
uniforms on (0, 1) (never 0 or 1: the largest normal is 6.7), and Box-Muller turns each pair of
uniforms into two independent standard normals: pair 0 gives the white noise on z_J and z_B,
pair 1 on z_K and the slider force's (ppann/lever.py). Within a sample that is SplitMix64 as
published (Java's SplittableRandom, NumPy's seeding; it passes BigCrush), and the samples'
seeds are SplitMix64 outputs of the key. tests/test_counter.py checks the published outputs,
the normals' moments, tails and independence across samples, steps and pairs, and the sums
over 100 steps; on a trained model's torque the check's rate over 30 seeds is NumPy's
generator's to within its standard error (docs/history.md).
"""

from __future__ import annotations

import numpy as np

GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_UNIT = 2.0**-32
NORMALS = 4
"""Normals per sample and step: z_J, z_B, z_K and the slider force."""


def splitmix(values: np.ndarray) -> np.ndarray:
    """SplitMix64's output function, elementwise on uint64 (wrapping arithmetic)."""
    z = values.astype(np.uint64)
    z = (z ^ (z >> np.uint64(30))) * _M1
    z = (z ^ (z >> np.uint64(27))) * _M2
    return z ^ (z >> np.uint64(31))


def key_of(sequence: np.random.SeedSequence) -> int:
    """The 64-bit key a SeedSequence stands for (its first generated word)."""
    return int(sequence.generate_state(1, np.uint64)[0])


def counter_normals(key: int, *, samples: int, steps: int, offset: int = 0) -> np.ndarray:
    """Standard normals (steps, samples, NORMALS) of samples offset..offset+samples-1 at steps
    0..steps-1 (a draw per trajectory is step 0's), as the kernel generates them."""
    if samples < 0 or steps < 0 or offset < 0:
        raise ValueError(
            f"counter_normals: samples {samples} from {offset}, steps {steps} out of range"
        )
    out = np.empty((steps, samples, NORMALS))
    with np.errstate(over="ignore"):
        index = np.arange(offset + 1, offset + samples + 1, dtype=np.uint64)
        seed = splitmix(np.uint64(key) + GOLDEN * index)
        for pair in range(2):
            at = GOLDEN * (2 * np.arange(steps, dtype=np.uint64) + np.uint64(pair + 1))
            z = splitmix(seed[None, :] + at[:, None])
            u1 = ((z >> np.uint64(32)).astype(np.float64) + 0.5) * _UNIT
            u2 = ((z & np.uint64(0xFFFFFFFF)).astype(np.float64) + 0.5) * _UNIT
            radius = np.sqrt(-2.0 * np.log(u1))
            out[..., 2 * pair] = radius * np.cos(2 * np.pi * u2)
            out[..., 2 * pair + 1] = radius * np.sin(2 * np.pi * u2)
    return out
