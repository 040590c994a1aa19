/* The ray-packet peer of a shot (scripts/bench-packets.sh): one ray per cell
 * of the equal-angle hemisphere (the cells' centre directions, as
 * `hemisphere::direction_table` computes them), cast with Embree 3's 8-ray
 * packets (rtcIntersect8), nearest hit into an item buffer, over the given
 * hemispheres; rows shared by the OpenMP threads (OMP_NUM_THREADS).
 *
 * Input (little-endian, from the script): u32 triangles, u32 hemispheres,
 * u32 rows, u32 cols, f32 extent; then 9 f32 per triangle; then 12 f32 per
 * hemisphere (centre, tangent, bitangent, normal).
 * Prints the median and mean milliseconds a hemisphere, and the hits. */
#include <embree3/rtcore.h>
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static void fail(const char *what) {
    fprintf(stderr, "packets: %s\n", what);
    exit(1);
}

static void read_all(FILE *f, void *p, size_t bytes) {
    if (fread(p, 1, bytes, f) != bytes) fail("input file is short");
}

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static int cmp(const void *a, const void *b) {
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int main(int argc, char **argv) {
    if (argc != 2) fail("usage: packets INPUT");
    FILE *f = fopen(argv[1], "rb");
    if (!f) fail("cannot open the input file");
    uint32_t head[4];
    float extent;
    read_all(f, head, sizeof head);
    read_all(f, &extent, sizeof extent);
    uint32_t ntri = head[0], nshot = head[1], rows = head[2], cols = head[3];
    if (cols % 8) fail("columns must be a multiple of 8");
    float *tris = malloc(sizeof(float) * 9 * ntri);
    float *shots = malloc(sizeof(float) * 12 * nshot);
    if (!tris || !shots) fail("out of memory");
    read_all(f, tris, sizeof(float) * 9 * ntri);
    read_all(f, shots, sizeof(float) * 12 * nshot);
    fclose(f);

    RTCDevice dev = rtcNewDevice(NULL);
    if (!dev) fail("rtcNewDevice failed");
    RTCScene scene = rtcNewScene(dev);
    /* The strongest peer: a static scene's best hierarchy, coherent rays. */
    rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_HIGH);
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    float *v = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                       3 * sizeof(float), 3 * (size_t)ntri);
    unsigned *ix = rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                           3 * sizeof(unsigned), ntri);
    memcpy(v, tris, sizeof(float) * 9 * ntri);
    for (unsigned i = 0; i < 3 * ntri; i++) ix[i] = i;
    rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_HIGH);
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(scene);

    /* The cells' centre directions, in f64 rounded to f32 (as the renderer). */
    float *sphi = malloc(sizeof(float) * rows), *cphi = malloc(sizeof(float) * rows);
    float *cth = malloc(sizeof(float) * cols), *sth = malloc(sizeof(float) * cols);
    for (uint32_t p = 0; p < rows; p++) {
        double phi = (p + 0.5) * M_PI_2 / rows;
        sphi[p] = (float)sin(phi);
        cphi[p] = (float)cos(phi);
    }
    for (uint32_t t = 0; t < cols; t++) {
        double th = (t + 0.5) * 2.0 * M_PI / cols;
        cth[t] = (float)cos(th);
        sth[t] = (float)sin(th);
    }
    unsigned *items = malloc(sizeof(unsigned) * rows * cols);
    double *ms = malloc(sizeof(double) * nshot);
    float tnear = 1e-5f * extent;
    unsigned long long hits = 0;
    for (uint32_t s = 0; s < nshot; s++) {
        const float *fr = shots + 12 * s;
        const float *c = fr, *tx = fr + 3, *by = fr + 6, *nz = fr + 9;
        double start = now();
        unsigned long long shot_hits = 0;
#pragma omp parallel for schedule(dynamic, 2) reduction(+ : shot_hits)
        for (uint32_t p = 0; p < rows; p++) {
            struct RTCIntersectContext ctx;
            rtcInitIntersectContext(&ctx);
            ctx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
            struct RTCRayHit8 rh;
            int valid[8] __attribute__((aligned(32)));
            for (int l = 0; l < 8; l++) valid[l] = -1;
            for (uint32_t t0 = 0; t0 < cols; t0 += 8) {
                for (int l = 0; l < 8; l++) {
                    uint32_t t = t0 + l;
                    float a = sphi[p] * cth[t], b = sphi[p] * sth[t], z = cphi[p];
                    rh.ray.org_x[l] = c[0];
                    rh.ray.org_y[l] = c[1];
                    rh.ray.org_z[l] = c[2];
                    rh.ray.dir_x[l] = a * tx[0] + b * by[0] + z * nz[0];
                    rh.ray.dir_y[l] = a * tx[1] + b * by[1] + z * nz[1];
                    rh.ray.dir_z[l] = a * tx[2] + b * by[2] + z * nz[2];
                    rh.ray.tnear[l] = tnear;
                    rh.ray.tfar[l] = INFINITY;
                    rh.ray.time[l] = 0.0f;
                    rh.ray.mask[l] = 0xFFFFFFFFu;
                    rh.ray.id[l] = l;
                    rh.ray.flags[l] = 0;
                    rh.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;
                    rh.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
                }
                rtcIntersect8(valid, scene, &ctx, &rh);
                for (int l = 0; l < 8; l++) {
                    int hit = rh.hit.geomID[l] != RTC_INVALID_GEOMETRY_ID;
                    items[p * cols + t0 + l] = hit ? rh.hit.primID[l] : 0xFFFFFFFFu;
                    shot_hits += hit;
                }
            }
        }
        ms[s] = 1e3 * (now() - start);
        hits += shot_hits;
    }
    double sum = 0;
    for (uint32_t s = 0; s < nshot; s++) sum += ms[s];
    qsort(ms, nshot, sizeof(double), cmp);
    printf("%u hemispheres of %u x %u over %u triangles, %d threads: median %.3f ms, mean %.3f ms, %.1f %% of rays hit\n",
           nshot, rows, cols, ntri, omp_get_max_threads(), ms[nshot / 2], sum / nshot,
           100.0 * hits / ((double)nshot * rows * cols));
    rtcReleaseScene(scene);
    rtcReleaseDevice(dev);
    return 0;
}
