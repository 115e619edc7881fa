"""The C source of the Monte-Carlo's compiled rollout: one function, `crank_rollout`, that runs
ppann/montecarlo.py's `rollout` (ppann/kernel.py builds, loads and calls it, and its docstring says
what the code does and why). Apart from kernel.py so that each stays one concept of readable
length; the library's cache key is this text, the flags and the CPU."""

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
                          machine_prior, coulomb motor, coulomb load, coulomb_speed, l1, l2,
                          linear_inertia, half_step */
    const double *table, int table_rows, int n_angle, const int *angle_out,
    const float *w_in, int hidden, int n_speed, const int *speed_out, const int *row_start,
    const int *row_end, const float *w_out, const double *b_out,
    const double *lever_eps, const double *lever_table, /* the slider force's channel, or NULL */
    int use_key, uint64_t key, int64_t offset, /* counter normals in place of eps (below) */
    const int *slot, int n_slots, /* state r (0..steps) is row slot[r] of a sample, or not kept */
    double *samples)
{
    const double dt = prm[0], jm = prm[1], bm = prm[2], km = prm[3], oscale = prm[4];
    const double sfloor = prm[5], ifloor = prm[6], cellscale = prm[7];
    const int use_nets = prm[8] != 0.0, machine_prior = prm[9] != 0.0;
    /* the prior's Coulomb friction (ppann/friction.py): motor torque, slider force */
    const double cmotor = prm[10], cload = prm[11], cspeed = prm[12], l1 = prm[13], l2 = prm[14];
    const int coulomb = cmotor != 0.0 || cload != 0.0;
    const int linear = prm[15] != 0.0;  /* z_J's white draw to first order (PPANNConfig) */
    const double half = prm[16];  /* the trapezoid angle update's dt^2 / 2, or 0 */
    const double two_pi = 6.283185307179586;
    const int np = (n + LANES - 1) / LANES * LANES;
    double *th = malloc(sizeof(double) * np * 3), *om = th + np, *ang = th + 2 * np;
    float *g = malloc(sizeof(float) * np * (3 + n_speed));
    double *out = malloc(sizeof(double) * np * 6);
    double *w = use_key ? malloc(sizeof(double) * np * 5) : NULL, *ws = w ? w + 4 * np : NULL;
    uint64_t *seed = use_key ? malloc(sizeof(uint64_t) * np) : NULL;
    unsigned char *bad = calloc(n, 1);
    if (!th || !g || !out || !bad || (use_key && (!w || !seed))) {
        free(th); free(g); free(out); free(w); free(seed); free(bad); return 1;
    }
    if (use_key)  /* each sample's own stream, seeded from the key (ppann/counter.py) */
        EACH(s) seed[s] = splitmix(key + GOLDEN * (uint64_t)(offset + (s < n ? s : n - 1) + 1));
    float *g0 = g, *g1 = g + np, *g2 = g + 2 * np, *acc = g + 3 * np;
    const size_t stride = (size_t)n_slots * 2;
    EACH(s) { th[s] = x0[0]; om[s] = x0[1]; }
    /* a diverged sample is NaN from its first non-finite state on (fast-math does not keep
       inf and NaN arithmetic to IEEE rules, so what came after it is not trusted); only the
       kept states are written (the tail check keeps 2 of 100: 32 MB of page faults less) */
    for (int s = 0, r = slot[0]; s < n; ++s) {
        bad[s] = !finite_bits(th[s]) || !finite_bits(om[s]);
        if (r >= 0) {
            samples[s * stride + 2 * r] = bad[s] ? NAN : th[s];
            samples[s * stride + 2 * r + 1] = bad[s] ? NAN : om[s];
        }
    }
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
            double d0 = 0.0;  /* z_J's white draw */
            if (e) {
                d0 = out[3 * np + s] * e[3 * src]; z1 += out[4 * np + s] * e[3 * src + 1];
                z2 += out[5 * np + s] * e[3 * src + 2];
            } else if (use_key) {
                d0 = out[3 * np + s] * w[s]; z1 += out[4 * np + s] * w[np + s];
                z2 += out[5 * np + s] * w[2 * np + s];
            }
            if (!linear) z0 += d0;
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
            if (coulomb) {  /* the prior's Coulomb friction, times the damping factor */
                const double sn = sin(ang[s]), cs = cos(ang[s]);
                const double slope = -l1 * sn * (1 + l1 * cs / sqrt(l2 * l2 - l1 * l1 * sn * sn));
                const double fr = cmotor * tanh(om[s] / cspeed)
                    + cload * slope * tanh(slope * om[s] / (cspeed * l1));
                u -= fr * (factors ? factors[3 * src + 1] : 1.0);
            }
            double f0 = 1 + z0, f1 = 1 + z1, f2 = 1 + z2;
            if (factors && machine_prior) {  /* the machine scales the prior's term alone */
                f0 += factors[3 * src] - 1; f1 += factors[3 * src + 1] - 1;
                f2 += factors[3 * src + 2] - 1;
            }
            const double floored = f0 > ifloor ? f0 : ifloor;
            double inertia = jm * floored;
            double damping = bm * f1 * om[s];
            double stiffness = km * f2 * ang[s];
            if (factors && !machine_prior) {
                inertia *= factors[3 * src]; damping *= factors[3 * src + 1];
                stiffness *= factors[3 * src + 2];
            }
            double next = th[s] + dt * om[s];
            double alpha = (u - damping - stiffness) / inertia;
            if (linear) alpha *= 1 - d0 / floored;  /* about the mean: zero-mean in eps */
            if (half != 0.0) next = next + half * alpha;
            om[s] = om[s] + dt * alpha;
            th[s] = next;
        }
        for (int s = 0, r = slot[k + 1]; s < n; ++s) {
            bad[s] |= !finite_bits(th[s]) || !finite_bits(om[s]);
            if (r >= 0) {
                samples[s * stride + 2 * r] = bad[s] ? NAN : th[s];
                samples[s * stride + 2 * r + 1] = bad[s] ? NAN : om[s];
            }
        }
    }
    free(th); free(g); free(out); free(w); free(seed); free(bad);
    return 0;
}
"""
