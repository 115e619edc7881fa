"""The Monte-Carlo's rollout (ppann/montecarlo.py `rollout`) as one C function, compiled once
per machine with the system's C compiler and called through ctypes.

Why: NumPy's rollout is a few dozen array operations per step on (n_samples,) arrays, and at
the robust loop's 1000 samples each costs more in NumPy's per-call overhead than in arithmetic;
the Monte-Carlo was half of the robust loop's time. Here one call runs every step, the samples
the inner loop of each stage (structure of arrays) so that GCC vectorises across them: the same
arithmetic as FusedHeads and FusedHeads.acceleration — the angle-only outputs from the same
float64 table, the speed networks in float32, softplus and floor in float64, the inertia factor
floored — except tanh, here a rational function inlined (`tanh_rational`, within 4e-7 of tanh;
FusedHeads computes 1 - 2 / (exp(2 x) + 1) with NumPy's float32 exp, within 2e-7). The two paths
agree to float32 rounding in the speed networks (tests/test_kernel.py bounds it), not bit for
bit: the sums run in another order and the tanh are not the same function.

Session 34 made the kernel 1.65x faster on one thread (20 000 trajectories of a trained model to
sample 100: 127 -> 77 ms; bench/bench_solve.py): the speed networks' tanh had called glibc's
vector expf and divided (45 % of the time), and the features' sin and cos, in one loop, had
become one scalar sincos per sample (16 %). A caller may keep only some states (`at`): the
tail check keeps its constraint samples, and its first call in a process took twice its later
ones (80 against 41 ms) in page faults of the 32 MB it wrote. Found then: under -ffast-math, an
edit anywhere in the C can change how GCC contracts and orders the float arithmetic, and with it
the numbers at float32 rounding (θ within 3e-6 rad over 149 steps): the tests bound the paths'
agreement, not bits, and an edit of the C is checked on decided torques and held-out machines
like a change of method (bench/kernel_tanh_seeds.md). Within the kernel, equal states give
bit-equal results wherever they sit among the samples (every sample runs through the vector
code, none through a scalar remainder loop).

The build: `cc -O3 -march=native -ffast-math -c` (fast-math lets GCC call glibc's vector sin,
cos, exp, log and log1p; finiteness is tested on the bits, which fast-math cannot assume away,
and the tanh's argument is clamped), then linked without fast-math (FLAGS says why), into a
per-user cache keyed by the source, the flags and the CPU, written beside its target and
renamed into place. Without a compiler, or if the build fails, `load()` returns None and the
NumPy path runs (the same numbers to float32 rounding, slower).
CRANK_KERNEL=0 forces the NumPy path.

Threads: a rollout of many trajectories runs as blocks of at least CHUNK_SAMPLES of them, one
per thread up to `common.threads.rollout_threads()` (every core unless set; a sweep's worker sets
one), since ctypes lets go of the GIL during the call. A sample's arithmetic does not depend on
its block, so the result is the same bits on any number of threads (tests/test_kernel.py).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import itertools
import os
import platform
import shutil
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from common.threads import rollout_threads
from ppann.heads import INERTIA_FACTOR_FLOOR, FusedHeads
from ppann.kernel_source import SOURCE

FLAGS = ("-O3", "-march=native", "-ffast-math", "-fPIC")
"""Compile flags. The link is apart and without -ffast-math: linked with it, GCC adds
crtfastmath.o, whose constructor sets flush-to-zero and denormals-are-zero for the whole process
when the library loads, and MuJoCo's and NumPy's arithmetic then changes (it broke the twin's
kinematics tests and gave the robust loop NaN margins)."""


def _cpu() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("model name", "flags")):
                return line
    except OSError:
        pass
    return platform.processor()


def _library_path() -> Path:
    key = hashlib.sha256("\n".join([SOURCE, *FLAGS, _cpu()]).encode()).hexdigest()[:16]
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "crank"
    return cache / f"rollout-{key}.so"


@functools.cache
def load() -> ctypes.CDLL | None:
    """The compiled kernel (built on first use), or None without a compiler or with
    CRANK_KERNEL=0."""
    if os.environ.get("CRANK_KERNEL", "1") == "0":
        return None
    compiler = shutil.which(os.environ.get("CC", "cc"))
    if compiler is None:
        return None
    target = _library_path()
    try:
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=target.parent) as folder:
                source = Path(folder) / "rollout.c"
                source.write_text(SOURCE)
                built = Path(folder) / target.name
                objects = Path(folder) / "rollout.o"
                for command in (
                    [compiler, *FLAGS, "-c", str(source), "-o", str(objects)],
                    [compiler, "-shared", str(objects), "-o", str(built), "-lm"],
                ):
                    subprocess.run(command, check=True, capture_output=True, timeout=120)
                os.replace(built, target)
        library = ctypes.CDLL(str(target))
    except (OSError, subprocess.SubprocessError):
        return None
    library.crank_rollout.restype = ctypes.c_int
    return library


CHUNK_SAMPLES = 256
"""Fewest trajectories a thread of one rollout takes: the robust loop's 1000 run on two cores as
two blocks of 500 (a thread costs ~0.1 ms to start, a block of 256 samples ~5 ms at 150 steps)."""


def _ptr(array: np.ndarray | None) -> ctypes.c_void_p | None:
    return None if array is None else array.ctypes.data_as(ctypes.c_void_p)


def rollout(
    heads: FusedHeads,
    x0: np.ndarray,
    tau: np.ndarray,
    *,
    n_samples: int,
    eps: np.ndarray | None,
    factors: np.ndarray | None,
    plan: np.ndarray | None,
    gains: np.ndarray | None,
    limit: float,
    per_step: bool,
    lever_eps: np.ndarray | None = None,
    key: int | None = None,
    at: np.ndarray | None = None,
    first: int = 0,
) -> np.ndarray | None:
    """ppann/montecarlo.py `rollout` in C: (n_samples, T + 1, 2), or with `at` (indices into
    the T + 1 states, increasing, as the caller checked) only those states, (n_samples,
    len(at), 2); None when the kernel is not available (the caller then runs NumPy's);
    `per_step`: eps (and `lever_eps`, the slider force's normals) has a row per step (else one
    row for the whole run), as the caller decided. `key` (with eps and lever_eps None): the
    white normals (and the slider force's, for a model with the channel) generated here,
    ppann/counter.py's `counter_normals(key)`, per step or per trajectory as `per_step` says,
    of trajectories `first`.. of the key's run."""
    if key is not None and (eps is not None or lever_eps is not None):
        raise ValueError("rollout: give the white normals as arrays or as a key, not both")
    library = load()
    if library is None:
        return None
    steps = tau.shape[0]

    def c64(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else np.ascontiguousarray(a, dtype=np.float64)

    def c32(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.float32)

    def ints(values: list[int]) -> np.ndarray:
        return np.ascontiguousarray(values, dtype=np.intc)

    kept = np.arange(steps + 1) if at is None else np.asarray(at, dtype=int)
    slot = np.full(steps + 1, -1, dtype=np.intc)
    slot[kept] = np.arange(kept.size)
    samples = np.empty((n_samples, kept.size, 2))
    x0 = c64(np.asarray(x0, dtype=float)[:2])
    tau, eps, factors = c64(tau), c64(eps), c64(factors)
    if plan is not None:
        plan, gains = c64(plan[:steps]), c64(gains[:steps])
    params = c64(
        np.array(
            [
                heads.dt,
                heads.j,
                heads.b,
                heads.k,
                heads.omega_scale,
                heads.sigma_floor,
                INERTIA_FACTOR_FLOOR,
                heads.cell,
                float(heads.use_networks),
                float(heads.machine_prior),
                *(heads.coulomb or (0.0, 0.0)),
                heads.coulomb_speed,
                heads.geometry.crank_length,
                heads.geometry.rod_length,
                float(heads.linear_inertia),
                heads.half_step,
            ]
        )
    )
    table = c64(heads.table)
    w_in, w_out = c32(heads.w_in), c32(np.concatenate(heads.w_out or [np.zeros(0)]))
    starts = ints([r.start for r in heads.rows])
    ends = ints([r.stop for r in heads.rows])
    angle_out, speed_out = ints(heads.angle_outputs), ints(heads.speed_outputs)
    b_out = c64(heads.b_out.ravel())
    lever_eps = c64(lever_eps)
    lever = lever_eps is not None or (key is not None and heads.has_lever)
    lever_table = c64(heads.lever_table) if lever else None

    def run(a: int, b: int) -> int:
        """Samples a..b-1 into samples[a:b] (a contiguous block of rows)."""
        part = slice(a, b)
        return library.crank_rollout(
            ctypes.c_int(b - a),
            ctypes.c_int(steps),
            ctypes.c_int(int(per_step)),
            ctypes.c_int(int(eps is not None)),
            _ptr(x0),
            _ptr(tau),
            _ptr(None if eps is None else np.ascontiguousarray(eps[:, part])),
            _ptr(None if factors is None else factors[part]),
            _ptr(plan),
            _ptr(gains),
            ctypes.c_double(limit),
            _ptr(params),
            _ptr(table),
            ctypes.c_int(table.shape[0]),
            ctypes.c_int(table.shape[1]),
            _ptr(angle_out),
            _ptr(w_in),
            ctypes.c_int(w_in.shape[1]),
            ctypes.c_int(len(heads.speed_outputs)),
            _ptr(speed_out),
            _ptr(starts),
            _ptr(ends),
            _ptr(w_out),
            _ptr(b_out),
            _ptr(None if lever_eps is None else np.ascontiguousarray(lever_eps[:, part])),
            _ptr(lever_table),
            ctypes.c_int(int(key is not None)),
            ctypes.c_uint64(0 if key is None else key),
            ctypes.c_int64(first + a),
            _ptr(slot),
            ctypes.c_int(kept.size),
            _ptr(samples[part]),
        )

    threads = max(1, min(rollout_threads(), n_samples // CHUNK_SAMPLES))
    block, *rest = itertools.pairwise(n_samples * i // threads for i in range(threads + 1))
    if not rest:
        return None if run(*block) else samples
    # ctypes lets go of the GIL during the call: the blocks run side by side
    with ThreadPoolExecutor(len(rest)) as pool:
        others = [pool.submit(run, a, b) for a, b in rest]
        failed = [run(*block), *(f.result() for f in others)]
    return None if any(failed) else samples
