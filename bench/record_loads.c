/* A vertex's three fields for 16 lanes at random indices: three AVX-512 gathers against one
 * masked 4-wide load per lane and a transpose, as compiler/backends/llvm_records.py lowers
 * them (the load masked to the 3 fields, so no lane reads past its record).
 *
 *     cc -O2 -mavx512f -mavx512vl -o /tmp/record_loads bench/record_loads.c && /tmp/record_loads
 *
 * Prints nanoseconds per 16-lane packet for each, three rounds (the table fits L1: the
 * cost of the instructions, not of cache misses). */
#include <immintrin.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define NV 4096
#define N (1 << 16)
#define REPS 200
static float P[NV * 3];
static int idx[N];

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec * 1e-9;
}

__attribute__((noinline, noipa)) static __m512 gathers(const int *ix, __mmask16 m) {
    __m512 acc = _mm512_setzero_ps();
    for (int i = 0; i < N; i += 16) {
        __m512i b = _mm512_mullo_epi32(_mm512_loadu_si512(ix + i), _mm512_set1_epi32(3));
        __m512 z0 = _mm512_setzero_ps();
        __m512 x = _mm512_mask_i32gather_ps(z0, m, b, P, 4);
        __m512 y = _mm512_mask_i32gather_ps(z0, m, _mm512_add_epi32(b, _mm512_set1_epi32(1)), P, 4);
        __m512 z = _mm512_mask_i32gather_ps(z0, m, _mm512_add_epi32(b, _mm512_set1_epi32(2)), P, 4);
        acc = _mm512_add_ps(acc, _mm512_fmadd_ps(x, y, z));
    }
    return acc;
}

__attribute__((noinline, noipa)) static __m512 rows(const int *ix, __mmask16 m) {
    __m512 acc = _mm512_setzero_ps();
    for (int i = 0; i < N; i += 16) {
        __m512i b = _mm512_mullo_epi32(_mm512_maskz_mov_epi32(m, _mm512_loadu_si512(ix + i)),
                                       _mm512_set1_epi32(3));
        int o[16];
        _mm512_storeu_si512(o, b);
        __m512 r[4];
        for (int q = 0; q < 4; q++) { /* r[q]'s 128-bit block k: the row of lane q + 4k */
            __m512 t = _mm512_castps128_ps512(_mm_maskz_loadu_ps(7, P + o[q]));
            t = _mm512_insertf32x4(t, _mm_maskz_loadu_ps(7, P + o[q + 4]), 1);
            t = _mm512_insertf32x4(t, _mm_maskz_loadu_ps(7, P + o[q + 8]), 2);
            r[q] = _mm512_insertf32x4(t, _mm_maskz_loadu_ps(7, P + o[q + 12]), 3);
        }
        __m512d t0 = _mm512_castps_pd(_mm512_unpacklo_ps(r[0], r[1]));
        __m512d t1 = _mm512_castps_pd(_mm512_unpacklo_ps(r[2], r[3]));
        __m512d t2 = _mm512_castps_pd(_mm512_unpackhi_ps(r[0], r[1]));
        __m512d t3 = _mm512_castps_pd(_mm512_unpackhi_ps(r[2], r[3]));
        __m512 x = _mm512_maskz_mov_ps(m, _mm512_castpd_ps(_mm512_unpacklo_pd(t0, t1)));
        __m512 y = _mm512_maskz_mov_ps(m, _mm512_castpd_ps(_mm512_unpackhi_pd(t0, t1)));
        __m512 z = _mm512_maskz_mov_ps(m, _mm512_castpd_ps(_mm512_unpacklo_pd(t2, t3)));
        acc = _mm512_add_ps(acc, _mm512_fmadd_ps(x, y, z));
    }
    return acc;
}

int main(void) {
    for (int i = 0; i < NV * 3; i++) P[i] = rand() / (float)RAND_MAX;
    for (int i = 0; i < N; i++) idx[i] = rand() % NV;
    float check = 0;
    for (int round = 0; round < 3; round++) {
        double t = now();
        for (int k = 0; k < REPS; k++) check += gathers(idx, 0xffff)[0];
        double tg = now() - t;
        t = now();
        for (int k = 0; k < REPS; k++) check -= rows(idx, 0xffff)[0];
        double tr = now() - t;
        double packets = (double)REPS * (N / 16);
        printf("3 gathers %.2f ns/packet   rows + transpose %.2f ns/packet\n",
               tg / packets * 1e9, tr / packets * 1e9);
    }
    /* the same values: the two sums cancel up to rounding */
    printf("difference of the sums (expect ~0): %g\n", check);
    return 0;
}
