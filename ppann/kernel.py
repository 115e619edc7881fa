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
become one scalar sincos per sample (16 %). Within the kernel, equal states give bit-equal results
wherever they sit among the samples (every sample runs through the vector code, none through a
scalar remainder loop).

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
from ppann.model import INERTIA_FACTOR_FLOOR, FusedHeads

SOURCE = r"""
#define _GNU_SOURCE
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define GOLDEN 0x9e3779b97f4a7c15ULL

/* SplitMix64's output function (ppann/counter.py) */
static inline uint64_t splitmix(uint64_t z) {
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/* tanh in float32 as a rational function (Eigen's generic_fast_tanh_float): odd degree 13
   over even degree 6, within 4e-7 of tanh on [-TANH_CLAMP, TANH_CLAMP], where it reaches 1.0f.
   Inline FMAs and one division, where 1 - 2 / (expf(2 x) + 1) called the vector expf: the
   speed networks in 0.45 of the time (module docstring). */
#define TANH_CLAMP 7.90531110763549805f
static inline float tanh_rational(float x) {
    const float x2 = x * x;
    float p = -2.76076847742355e-16f;
    p = p * x2 + 2.00018790482477e-13f;
    p = p * x2 - 8.60467152213735e-11f;
    p = p * x2 + 5.12229709037114e-08f;
    p = p * x2 + 1.48572235717979e-05f;
    p = p * x2 + 6.37261928875436e-04f;
    p = p * x2 + 4.89352455891786e-03f;
    float q = 1.19825839466702e-06f;
    q = q * x2 + 1.18534705686654e-04f;
    q = q * x2 + 2.26843463243900e-03f;
    q = q * x2 + 4.89352518554385e-03f;
    return x * p / q;
}

static int finite_bits(double x) {
    uint64_t u; memcpy(&u, &x, 8);
    return ((u >> 52) & 0x7ff) != 0x7ff;
}

/* Samples are the inner loop of every stage (structure of arrays), so that GCC vectorises
   across them, sin, cos, exp, log and log1p through glibc's vector math library. Every loop
   over samples runs in whole blocks of LANES (n padded with copies of the last sample), so no
   sample falls in a scalar remainder loop, where the scalar functions round otherwise: equal
   states give bit-equal results wherever they sit. Returns 0, or 1 if the workspace could not
   be allocated. */
#define LANES 64
#define EACH(s) \
    for (int b_ = 0; b_ < np; b_ += LANES) \
        for (int l_ = 0, s = b_; l_ < LANES; ++l_, s = b_ + l_)
int crank_rollout(
    int n, int steps, int eps_per_step, int has_eps,
    const double *x0, const double *tau, const double *eps, const double *factors,
    const double *plan, const double *gains, double limit,
    const double *prm, /* dt, j, b, k, omega_scale, sigma_floor, inertia_floor, cell, use_nets,
                          machine_prior */
    const double *table, int table_rows, int n_angle, const int *angle_out,
    const float *w_in, int hidden, int n_speed, const int *speed_out, const int *row_start,
    const int *row_end, const float *w_out, const double *b_out,
    const double *lever_eps, const double *lever_table, /* the slider force's channel, or NULL */
    int use_key, uint64_t key, int64_t offset, /* counter normals in place of eps (below) */
    double *samples)
{
    const double dt = prm[0], jm = prm[1], bm = prm[2], km = prm[3], oscale = prm[4];
    const double sfloor = prm[5], ifloor = prm[6], cellscale = prm[7];
    const int use_nets = prm[8] != 0.0, machine_prior = prm[9] != 0.0;
    const double two_pi = 6.283185307179586;
    const int np = (n + LANES - 1) / LANES * LANES;
    double *th = malloc(sizeof(double) * np * 3), *om = th + np, *ang = th + 2 * np;
    float *g = malloc(sizeof(float) * np * (3 + n_speed));
    double *out = malloc(sizeof(double) * np * 6);
    double *w = use_key ? malloc(sizeof(double) * np * 5) : NULL, *ws = w ? w + 4 * np : NULL;
    uint64_t *seed = use_key ? malloc(sizeof(uint64_t) * np) : NULL;
    if (!th || !g || !out || (use_key && (!w || !seed))) {
        free(th); free(g); free(out); free(w); free(seed); return 1;
    }
    if (use_key)  /* each sample's own stream, seeded from the key (ppann/counter.py) */
        EACH(s) seed[s] = splitmix(key + GOLDEN * (uint64_t)(offset + (s < n ? s : n - 1) + 1));
    float *g0 = g, *g1 = g + np, *g2 = g + 2 * np, *acc = g + 3 * np;
    const size_t stride = (size_t)(steps + 1) * 2;
    EACH(s) { th[s] = x0[0]; om[s] = x0[1]; }
    for (int s = 0; s < n; ++s) { samples[s * stride] = x0[0]; samples[s * stride + 1] = x0[1]; }
    for (int k = 0; k < steps; ++k) {
        EACH(s) {
            double a = th[s] - two_pi * floor(th[s] / two_pi);  /* theta mod 2 pi */
            ang[s] = a < 0 ? 0 : a;
            g2[s] = (float)(om[s] / oscale);
        }
        /* apart, as the normals' below: in one loop GCC makes sin and cos one scalar sincos */
        EACH(s) g0[s] = (float)sin(ang[s]);
        EACH(s) g1[s] = (float)cos(ang[s]);
        memset(acc, 0, sizeof(float) * np * n_speed);
        for (int j = 0; j < n_speed; ++j) {
            float *aj = acc + (size_t)j * np;
            for (int h = row_start[j]; h < row_end[j]; ++h) {
                const float a0 = w_in[h], a1 = w_in[hidden + h], a2 = w_in[2 * hidden + h];
                const float a3 = w_in[3 * hidden + h], wo = w_out[h];
                EACH(s) {
                    float x = g0[s] * a0 + g1[s] * a1 + g2[s] * a2 + a3;
                    x = x > TANH_CLAMP ? TANH_CLAMP : (x < -TANH_CLAMP ? -TANH_CLAMP : x);
                    aj[s] += tanh_rational(x) * wo;
                }
            }
        }
        for (int j = 0; j < n_speed; ++j) {
            const int i = speed_out[j];
            const float *aj = acc + (size_t)j * np;
            double *oi = out + (size_t)i * np;
            EACH(s) {
                double v = (double)aj[s] + b_out[j];
                if (i >= 3) v = fmax(v, 0.0) + log1p(exp(-fabs(v))) + sfloor;
                oi[s] = v;
            }
        }
        EACH(s) {
            double at = ang[s] * cellscale;
            /* a diverged sample (theta huge or not finite): any cell will do */
            if (!finite_bits(at) || at < 0 || at > table_rows - 1) at = 0;
            int cell = (int)at;
            if (cell > table_rows - 2) cell = table_rows - 2;
            double frac = at - cell;
            for (int c = 0; c < n_angle; ++c)
                out[(size_t)angle_out[c] * np + s] = table[(size_t)cell * n_angle + c] * (1 - frac)
                    + table[(size_t)(cell + 1) * n_angle + c] * frac;
        }
        const double *e = has_eps ? eps + (size_t)(eps_per_step ? k : 0) * n * 3 : NULL;
        if (use_key && (eps_per_step || k == 0)) {
            /* sample (offset + s)'s four normals of step k (of step 0 for a draw per
               trajectory): Box-Muller on outputs 2 k + 1 and 2 k + 2 of the SplitMix64
               stream seeded with the sample's seed (ppann/counter.py) */
            const uint64_t step = eps_per_step ? (uint64_t)k : 0;
            for (int p = 0; p < 2; ++p) {
                double *wa = w + (size_t)(2 * p) * np, *wb = wa + np;
                const uint64_t at = GOLDEN * (2 * step + (uint64_t)p + 1);
                EACH(s) {
                    const uint64_t z = splitmix(seed[s] + at);
                    const double u1 = ((double)(z >> 32) + 0.5) * 2.3283064365386963e-10;
                    const double u2 = ((double)(z & 0xffffffffULL) + 0.5)
                        * 2.3283064365386963e-10;
                    wa[s] = sqrt(-2.0 * log(u1));
                    ws[s] = two_pi * u2;
                }
                /* apart: in one loop GCC makes sin and cos one sincos, which it does not
                   vectorise */
                EACH(s) wb[s] = wa[s] * sin(ws[s]);
                EACH(s) wa[s] *= cos(ws[s]);
            }
        }
        EACH(s) {
            const int src = s < n ? s : n - 1;  /* a padding lane repeats the last sample */
            double z0 = use_nets ? out[s] : 0.0, z1 = use_nets ? out[np + s] : 0.0;
            double z2 = use_nets ? out[2 * np + s] : 0.0;
            if (e) {
                z0 += out[3 * np + s] * e[3 * src]; z1 += out[4 * np + s] * e[3 * src + 1];
                z2 += out[5 * np + s] * e[3 * src + 2];
            } else if (use_key) {
                z0 += out[3 * np + s] * w[s]; z1 += out[4 * np + s] * w[np + s];
                z2 += out[5 * np + s] * w[2 * np + s];
            }
            double u = tau[k];
            if (plan) {
                u = tau[k] - gains[2 * k] * (th[s] - plan[2 * k])
                    - gains[2 * k + 1] * (om[s] - plan[2 * k + 1]);
                u = u < -limit ? -limit : (u > limit ? limit : u);
            }
            if (lever_table) {  /* a load disturbance, after the law's saturation */
                double at = ang[s] * cellscale;
                if (!finite_bits(at) || at < 0 || at > table_rows - 1) at = 0;
                int cell = (int)at;
                if (cell > table_rows - 2) cell = table_rows - 2;
                double frac = at - cell;
                u += (lever_table[cell] * (1 - frac) + lever_table[cell + 1] * frac)
                    * (use_key ? w[3 * np + s]
                               : lever_eps[(size_t)(eps_per_step ? k : 0) * n + src]);
            }
            double f0 = 1 + z0, f1 = 1 + z1, f2 = 1 + z2;
            if (factors && machine_prior) {  /* the machine scales the prior's term alone */
                f0 += factors[3 * src] - 1; f1 += factors[3 * src + 1] - 1;
                f2 += factors[3 * src + 2] - 1;
            }
            double inertia = jm * (f0 > ifloor ? f0 : ifloor);
            double damping = bm * f1 * om[s];
            double stiffness = km * f2 * ang[s];
            if (factors && !machine_prior) {
                inertia *= factors[3 * src]; damping *= factors[3 * src + 1];
                stiffness *= factors[3 * src + 2];
            }
            double next = th[s] + dt * om[s];
            om[s] = om[s] + dt * (u - damping - stiffness) / inertia;
            th[s] = next;
        }
        for (int s = 0; s < n; ++s) {
            samples[s * stride + 2 * (k + 1)] = th[s];
            samples[s * stride + 2 * (k + 1) + 1] = om[s];
        }
    }
    /* a diverged sample is NaN from its first non-finite state on (fast-math does not keep
       inf and NaN arithmetic to IEEE rules, so what came after it is not trusted) */
    for (int s = 0; s < n; ++s) {
        double *row = samples + s * stride;
        for (int r = 0; r <= steps; ++r) {
            if (!finite_bits(row[2 * r]) || !finite_bits(row[2 * r + 1])) {
                for (; r <= steps; ++r) { row[2 * r] = NAN; row[2 * r + 1] = NAN; }
                break;
            }
        }
    }
    free(th); free(g); free(out); free(w); free(seed);
    return 0;
}
"""

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
) -> np.ndarray | None:
    """ppann/montecarlo.py `rollout` in C: (n_samples, T + 1, 2), or None when the kernel is
    not available (the caller then runs NumPy's); `per_step`: eps (and `lever_eps`, the slider
    force's normals) has a row per step (else one row for the whole run), as the caller
    decided. `key` (with eps and lever_eps None): the white normals (and the slider force's,
    for a model with the channel) generated here, ppann/counter.py's `counter_normals(key)`,
    per step or per trajectory as `per_step` says."""
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

    samples = np.empty((n_samples, steps + 1, 2))
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
            ctypes.c_int64(a),
            _ptr(samples[part]),
        )

    threads = max(1, min(rollout_threads(), n_samples // CHUNK_SAMPLES))
    first, *rest = itertools.pairwise(n_samples * i // threads for i in range(threads + 1))
    if not rest:
        return None if run(*first) else samples
    # ctypes lets go of the GIL during the call: the blocks run side by side
    with ThreadPoolExecutor(len(rest)) as pool:
        others = [pool.submit(run, a, b) for a, b in rest]
        failed = [run(*first), *(f.result() for f in others)]
    return None if any(failed) else samples
