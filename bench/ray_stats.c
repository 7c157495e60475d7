/* Ray statistics of a render: an LD_PRELOAD shim around Embree's rtcIntersect16 and
 * rtcOccluded16 (the packets of rdsl's avx512 kernels) that counts calls, active lanes per
 * call, and TSC cycles inside Embree (wall-clock cycles: a loaded machine inflates them).
 *
 *     cc -O2 -shared -fPIC -o /tmp/ray_stats.so bench/ray_stats.c -ldl
 *     LD_PRELOAD=/tmp/ray_stats.so python -c "import rdsl; \
 *         rdsl.load_scene('scene.xml', target='avx512').render(spp=64, threads=1)"
 *
 * The report is printed to stderr at exit. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <x86intrin.h>

typedef void (*query16)(const int *, void *, void *, void *);
static query16 real[2];
static const char *names[2] = {"rtcIntersect16", "rtcOccluded16"};
static _Atomic long calls[2], lanes[2], cycles[2], hist[2][17];

static void query(int q, const int *valid, void *scene, void *rays, void *args) {
    if (!real[q]) real[q] = (query16)dlsym(RTLD_NEXT, names[q]);
    int n = 0;
    for (int i = 0; i < 16; i++) n += valid[i] != 0;
    uint64_t t0 = __rdtsc();
    real[q](valid, scene, rays, args);
    cycles[q] += (long)(__rdtsc() - t0);
    calls[q]++;
    lanes[q] += n;
    hist[q][n]++;
}

void rtcIntersect16(const int *v, void *s, void *r, void *a) { query(0, v, s, r, a); }
void rtcOccluded16(const int *v, void *s, void *r, void *a) { query(1, v, s, r, a); }

__attribute__((destructor)) static void report(void) {
    for (int q = 0; q < 2; q++) {
        if (!calls[q]) continue;
        fprintf(stderr, "%s: %ld calls, %ld rays (%.2f active lanes of 16 per call), "
                "%.1f TSC cycles per ray\n  calls by active lanes:", names[q], calls[q],
                lanes[q], (double)lanes[q] / calls[q], (double)cycles[q] / lanes[q]);
        for (int k = 1; k <= 16; k++)
            fprintf(stderr, " %d:%.1f%%", k, 100.0 * hist[q][k] / calls[q]);
        fprintf(stderr, "\n");
    }
}
