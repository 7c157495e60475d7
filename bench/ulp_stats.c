/* Exhaustive ulp sweeps in one pass: the float64 truth (libm) and the error statistics of
   bench/ulp.py, about 20x faster than numpy. Built on demand by bench/ulp.py with cc; the
   definitions match runtime/testkit/ulp.py's ulp_error exactly (see its docstring). */
#include <math.h>
#include <stdint.h>
#include <string.h>

/* erfinv in float64: Giles' approximation as a seed, then Newton steps on erf(y) = |x|
   (through erfc(y) = 1 - |x| past 1/2, where 1 - |x| is exact) until they stop moving. */
static double erfinv(double x) {
    double a = fabs(x);
    if (!(a <= 1.0)) return NAN;
    if (a == 1.0) return copysign(INFINITY, x);
    if (a == 0.0) return x;
    double w = -log((1.0 - a) * (1.0 + a)), y;
    if (w < 5.0) {
        w -= 2.5;
        y = 2.81022636e-8;
        const double c[] = {3.43273939e-7, -3.5233877e-6, -4.39150654e-6, 2.1858087e-4,
                            -1.25372503e-3, -4.17768164e-3, 0.246640727, 1.50140941};
        for (int k = 0; k < 8; k++) y = y * w + c[k];
    } else {
        w = sqrt(w) - 3.0;
        y = -2.00214257e-4;
        const double c[] = {1.00950558e-4, 1.34934322e-3, -3.67342844e-3, 5.73950773e-3,
                            -7.6224613e-3, 9.43887047e-3, 1.00167406, 2.83297682};
        for (int k = 0; k < 8; k++) y = y * w + c[k];
    }
    y *= a;
    for (int k = 0; k < 6; k++) {
        double r = a <= 0.5 ? erf(y) - a : (1.0 - a) - erfc(y);
        y -= r / (1.1283791670955126 * exp(-y * y));
    }
    return copysign(y, x);
}

static double truth(int fn, double x) {
    switch (fn) {
    case 0: return sin(x);   case 1: return cos(x);   case 2: return tan(x);
    case 3: return asin(x);  case 4: return acos(x);  case 5: return atan(x);
    case 6: return exp(x);   case 7: return exp2(x);  case 8: return log(x);
    case 9: return log2(x);  case 10: return sqrt(x); case 11: return 1.0 / sqrt(x);
    case 12: return erf(x);
    case 13: return erfinv(x);
    default: return NAN;
    }
}

static double spacing(float r32) {
    uint32_t b;
    memcpy(&b, &r32, 4);
    int e = (b >> 23) & 0xff;
    if (e == 255) return ldexp(1.0, 104);
    return ldexp(1.0, (e < 1 ? 1 : e) - 150);
}

static double ulp_error(double got, double ref) {
    float r32 = (float)ref;
    double err = fabs(got - ref) / spacing(r32);
    if (!isfinite(got) || !isfinite(r32)) {
        int same = (isnan(got) && isnan(ref)) ||
                   (isinf(got) && isinf(r32) && (got > 0) == (ref > 0));
        if (same) err = 0.0;
        if (isnan(got) != isnan(ref)) err = INFINITY;
    }
    return err;
}

/* fn >= 0: the truth from libm; fn < 0: from ref[] (for functions libm lacks).
   out: max error on [lo, hi], its input, sum of finite errors, count, special mismatches */
void ulp_stats(const float *x, const float *got, const double *ref, int64_t n, int fn,
               double lo, double hi, double *out) {
    double worst = 0.0, at = 0.0, total = 0.0, count = 0.0, bad = 0.0;
    for (int64_t i = 0; i < n; i++) {
        double r = fn >= 0 ? truth(fn, (double)x[i]) : ref[i];
        double g = (double)got[i];
        if (x[i] >= lo && x[i] <= hi) {
            double e = ulp_error(g, r);
            if (e > worst) { worst = e; at = x[i]; }
            if (isfinite(e)) total += e;
            count += 1.0;
        }
        if (!isfinite(r) || r == 0.0)
            bad += !((isnan(g) && isnan(r)) || g == r);
    }
    out[0] = worst; out[1] = at; out[2] = total; out[3] = count; out[4] = bad;
}

/* Two arguments: fn 0 is pow(x, y), 1 is atan2(x, y) (x the first argument, as in C).
   The max and mean are over the pairs whose rounded truth is finite (and normal, with
   normal_only). Special values (a truth that is NaN or zero, or rounds to an infinity) must
   come out exactly, the sign of a zero included.
   out: max error, its x, its y, sum of finite errors, count, special mismatches */
void ulp_stats2(const float *x, const float *y, const float *got, int64_t n, int fn,
                int normal_only, double *out) {
    double worst = 0.0, wx = 0.0, wy = 0.0, total = 0.0, count = 0.0, bad = 0.0;
    for (int64_t i = 0; i < n; i++) {
        double a = (double)x[i], b = (double)y[i];
        double r = fn == 0 ? pow(a, b) : atan2(a, b);
        double g = (double)got[i];
        float r32 = (float)r;
        if (isfinite(r32) && (!normal_only || fabs(r32) >= 1.1754943508222875e-38)) {
            double e = ulp_error(g, r);
            if (e > worst) { worst = e; wx = a; wy = b; }
            if (isfinite(e)) total += e;
            count += 1.0;
        }
        if (!isfinite(r32) || r == 0.0)
            bad += !((isnan(g) && isnan(r)) || (g == r32 && signbit(g) == signbit(r)));
    }
    out[0] = worst; out[1] = wx; out[2] = wy; out[3] = total; out[4] = count; out[5] = bad;
}
