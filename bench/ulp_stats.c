/* Exhaustive ulp sweeps in one pass: the float64 truth (libm) and the error statistics of
   bench/ulp.py, about 20x faster than numpy. Built on demand by bench/ulp.py with cc; the
   definitions match runtime/testkit/ulp.py's ulp_error exactly (see its docstring). */
#include <math.h>
#include <stdint.h>
#include <string.h>

static double truth(int fn, double x) {
    switch (fn) {
    case 0: return sin(x);   case 1: return cos(x);   case 2: return tan(x);
    case 3: return asin(x);  case 4: return acos(x);  case 5: return atan(x);
    case 6: return exp(x);   case 7: return exp2(x);  case 8: return log(x);
    case 9: return log2(x);  case 10: return sqrt(x); case 11: return 1.0 / sqrt(x);
    case 12: return erf(x);
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
