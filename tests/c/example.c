/* A C program using the tactile-mirror C ABI (tm.h): configure, step, block, status,
 * and every error path (null pointers, bad sizes, invalid and stale handles, a
 * detector made for another sample rate). Exits 0 and prints "ok" when all checks
 * pass.
 *
 *   example            run the checks
 *   example N          then time N ticks through tm_pipeline_step (6 ridges) and print
 *                      "capi_ns_per_tick_f64 <ns>", "inside_ns_per_tick_f64 <ns>" (and _f32,
 *                      _f64f32: double filters, float detector)
 *   example N S        and run S seconds paced at 10 kHz (busy wait on CLOCK_MONOTONIC),
 *                      printing the tick latency percentiles "latency_ns p50 p99 p999 max"
 *                      and "overruns <ticks that ended after their deadline>"
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "tm.h"

#define R 6
#define H 16
#define NI (4 * R)
#define NO (2 + 3 * R)
#define T 2000

static int failures = 0;

#define CHECK(cond)                                                              \
    do {                                                                         \
        if (!(cond)) {                                                           \
            fprintf(stderr, "%s:%d: check failed: %s (last error: %s)\n", __FILE__, \
                    __LINE__, #cond, tm_last_error());                          \
            ++failures;                                                          \
        }                                                                        \
    } while (0)

static double w1[H * 5], b1[H], w2[2 * H], b2[2];
static const double mean[4] = {0.0, 0.0, 0.0, 0.0};
static const double gain[4] = {2.0, 2.0, 0.5, 0.5};
/* A 2nd-order low-pass and a band-limited differentiator at fs = 1 kHz. */
static const double sos_v[6] = {0.0675, 0.1349, 0.0675, 1.0, -1.1430, 0.4128};
static const double sos_u[12] = {0.2, 0.0, -0.2, 1.0, -0.5, 0.1, 1.0, 0.5, 0.0, 1.0, -0.3, 0.0};

static void make_weights(void) {
    unsigned s = 12345u;
    for (int i = 0; i < H * 5; ++i) { s = s * 1103515245u + 12345u; w1[i] = ((s >> 8) % 2001 - 1000) / 500.0; }
    for (int i = 0; i < H; ++i) { s = s * 1103515245u + 12345u; b1[i] = ((s >> 8) % 2001 - 1000) / 1000.0; }
    for (int i = 0; i < 2 * H; ++i) { s = s * 1103515245u + 12345u; w2[i] = ((s >> 8) % 2001 - 1000) / 300.0; }
    b2[0] = -1.0;
    b2[1] = -0.5;
}

static void base_config(tm_config* c) {
    tm_config_init(c);
    c->n_ridges = R;
    c->fs = 1000.0;
    c->use_u = 1;
    c->sos_v = sos_v;
    c->n_sos_v = 1;
    c->sos_u = sos_u;
    c->n_sos_u = 2;
    c->v_limit = 10.0;
    c->u_limit = 10.0;
    c->n_hidden = H;
    c->w1 = w1;
    c->b1 = b1;
    c->w2 = w2;
    c->b2 = b2;
    c->input_mean = mean;
    c->input_gain = gain;
    c->weights_fs = 1000.0;
    c->activation = 1;
    c->controller.kind = TM_CONTROLLER_VELOCITY;
    c->controller.threshold = 0.3;
    c->controller.y_full = 0.7;
    c->controller.v_max = 0.02;
    c->controller.a_max = 1.0;
}

static double now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec * 1e9 + ts.tv_nsec;
}

static void run_checks(int precision, int detector_precision) {
    tm_config cfg;
    tm_pipeline h = 0, h2 = 0;
    static double x[T * NI], out_step[T * NO], out_block[T * NO];
    double out[NO], feat[R * 4];
    size_t ni = 0, no = 0, nrej = 0;
    unsigned char acc[T];
    tm_pipeline_status st;

    CHECK(tm_abi_version() == TM_ABI_VERSION);
    CHECK(strlen(tm_version_string()) > 0);
    CHECK(tm_config_init(NULL) == TM_ERR_NULL);
    CHECK(strlen(tm_last_error()) > 0);

    /* configuration errors */
    base_config(&cfg);
    cfg.precision = precision;
    cfg.detector_precision = detector_precision;
    CHECK(tm_pipeline_create(NULL, &h) == TM_ERR_NULL);
    CHECK(tm_pipeline_create(&cfg, NULL) == TM_ERR_NULL);
    cfg.struct_size = 8;
    CHECK(tm_pipeline_create(&cfg, &h) == TM_ERR_VERSION);
    CHECK(h == 0);
    base_config(&cfg);
    cfg.precision = precision;
    cfg.detector_precision = detector_precision;
    cfg.weights_fs = 2000.0;
    CHECK(tm_pipeline_create(&cfg, &h) == TM_ERR_FS);
    base_config(&cfg);
    cfg.precision = precision;
    cfg.detector_precision = detector_precision;
    cfg.controller.v_max = -1.0;
    CHECK(tm_pipeline_create(&cfg, &h) == TM_ERR_ARGUMENT);
    CHECK(strstr(tm_last_error(), "v_max") != NULL);
    base_config(&cfg);
    cfg.precision = precision;
    cfg.detector_precision = detector_precision;
    cfg.w1 = NULL;
    CHECK(tm_pipeline_create(&cfg, &h) == TM_ERR_ARGUMENT);
    base_config(&cfg);
    cfg.precision = precision;
    cfg.detector_precision = detector_precision;
    cfg.n_ridges = 0;
    CHECK(tm_pipeline_create(&cfg, &h) == TM_ERR_ARGUMENT);
    base_config(&cfg);
    cfg.precision = 16;
    CHECK(tm_pipeline_create(&cfg, &h) == TM_ERR_ARGUMENT);

    /* a working pipeline */
    base_config(&cfg);
    cfg.precision = precision;
    cfg.detector_precision = detector_precision;
    CHECK(tm_pipeline_create(&cfg, &h) == TM_OK);
    CHECK(h != 0);
    CHECK(tm_pipeline_sizes(h, &ni, &no) == TM_OK);
    CHECK(ni == NI && no == NO);
    CHECK(tm_pipeline_sizes(h, NULL, &no) == TM_ERR_NULL);

    for (int t = 0; t < T; ++t)
        for (int c = 0; c < NI; ++c) x[t * NI + c] = 0.5 * sin(0.003 * t * (c + 1) + c) + 0.1 * cos(0.05 * t);
    x[500 * NI + 3] = NAN;
    x[900 * NI + 20] = 25.0;  /* beyond u_limit */

    /* argument errors leave the pipeline untouched */
    CHECK(tm_pipeline_step(h, NULL, NI, out, NO) == TM_ERR_NULL);
    CHECK(tm_pipeline_step(h, x, NI - 1, out, NO) == TM_ERR_SIZE);
    CHECK(tm_pipeline_step(h, x, NI, out, NO + 1) == TM_ERR_SIZE);
    CHECK(tm_pipeline_step(0, x, NI, out, NO) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_step(h + 1, x, NI, out, NO) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_step(h ^ ((tm_pipeline)7 << 40), x, NI, out, NO) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_step((tm_pipeline)-1, x, NI, out, NO) == TM_ERR_HANDLE);
    st.struct_size = sizeof st;
    CHECK(tm_pipeline_get_status(h, &st) == TM_OK);
    CHECK(st.ticks == 0);
    st.struct_size = 2;
    CHECK(tm_pipeline_get_status(h, &st) == TM_ERR_VERSION);
    CHECK(tm_pipeline_get_status(h, NULL) == TM_ERR_NULL);
    CHECK(tm_pipeline_reset(h, NAN) == TM_ERR_ARGUMENT);

    /* step through the signal */
    for (int t = 0; t < T; ++t) {
        int rc = tm_pipeline_step(h, x + t * NI, NI, out_step + t * NO, NO);
        if (t == 500 || t == 900) {
            CHECK(rc == TM_REJECTED);
            /* detector outputs held */
            CHECK(memcmp(out_step + t * NO + 2, out_step + (t - 1) * NO + 2, 3 * R * sizeof(double)) == 0);
        } else {
            CHECK(rc == TM_OK);
        }
    }
    st.struct_size = sizeof st;
    CHECK(tm_pipeline_get_status(h, &st) == TM_OK);
    CHECK(st.ticks == T && st.rejected == 2 && st.nonfinite == 1 && st.out_of_range == 1);
    CHECK(st.last_bad_tick == 900 && st.last_bad_channel == 20);
    for (int k = 0; k < T * NO; ++k) CHECK(isfinite(out_step[k]));
    CHECK(tm_pipeline_features(h, feat, R * 4) == TM_OK);
    CHECK(tm_pipeline_features(h, feat, 3) == TM_ERR_SIZE);

    /* the block call equals the steps, bit for bit */
    CHECK(tm_pipeline_reset(h, 0.0) == TM_OK);
    CHECK(tm_pipeline_process_block(h, x, T, NI, out_block, NO, acc, &nrej) == TM_OK);
    CHECK(nrej == 2 && acc[500] == 0 && acc[900] == 0 && acc[0] == 1);
    CHECK(memcmp(out_step, out_block, sizeof out_step) == 0);
    CHECK(tm_pipeline_process_block(h, x, T, NI + 1, out_block, NO, NULL, NULL) == TM_ERR_SIZE);
    CHECK(tm_pipeline_process_block(h, NULL, T, NI, out_block, NO, NULL, NULL) == TM_ERR_NULL);
    CHECK(tm_pipeline_process_block(h, NULL, 0, NI, NULL, NO, NULL, NULL) == TM_OK);

    /* a second pipeline is independent */
    CHECK(tm_pipeline_create(&cfg, &h2) == TM_OK);
    CHECK(h2 != h);
    CHECK(tm_pipeline_step(h2, x, NI, out, NO) == TM_OK);
    CHECK(tm_pipeline_set_position(h2, 0.01) == TM_OK);
    CHECK(tm_pipeline_destroy(h2) == TM_OK);

    /* destroyed handles are refused, never dereferenced */
    CHECK(tm_pipeline_destroy(h) == TM_OK);
    CHECK(tm_pipeline_destroy(h) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_step(h, x, NI, out, NO) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_reset(h, 0.0) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_destroy(0) == TM_ERR_HANDLE);
    CHECK(strcmp(tm_status_name(TM_ERR_HANDLE), "TM_ERR_HANDLE") == 0);
}

static void run_timing(long n, int precision, int detector_precision) {
    tm_config cfg;
    tm_pipeline h = 0;
    static double x[1024 * NI];
    double out[NO], ns_inside = 0.0;
    base_config(&cfg);
    cfg.precision = precision;
    cfg.detector_precision = detector_precision;
    if (tm_pipeline_create(&cfg, &h) != TM_OK) {
        fprintf(stderr, "create failed: %s\n", tm_last_error());
        ++failures;
        return;
    }
    for (int t = 0; t < 1024; ++t)
        for (int c = 0; c < NI; ++c) x[t * NI + c] = 1e-3 * sin(0.01 * t * (c + 1) + c);
    double best = 1e30;
    for (int r = 0; r < 5; ++r) {
        double t0 = now_ns();
        for (long i = 0; i < n; ++i) tm_pipeline_step(h, x + (i & 1023) * NI, NI, out, NO);
        double dt = (now_ns() - t0) / (double)n;
        if (dt < best) best = dt;
    }
    tm_pipeline_time_step_ns(h, n, &ns_inside);
    const char* tag = detector_precision == 32 && precision == 64 ? "f64f32" : (precision == 64 ? "f64" : "f32");
    printf("capi_ns_per_tick_%s %.1f\n", tag, best);
    printf("inside_ns_per_tick_%s %.1f\n", tag, ns_inside);
    tm_pipeline_destroy(h);
}

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

static void run_paced(double seconds) {
    const double period = 1e5; /* ns: 10 kHz */
    const long n = (long)(seconds * 1e4);
    tm_config cfg;
    tm_pipeline h = 0;
    static double x[1024 * NI];
    double out[NO];
    double* lat = (double*)malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    long overruns = 0;
    if (!lat) return;
    base_config(&cfg);
    cfg.fs = 10000.0;
    cfg.weights_fs = 10000.0;
    if (tm_pipeline_create(&cfg, &h) != TM_OK) {
        free(lat);
        ++failures;
        return;
    }
    for (int t = 0; t < 1024; ++t)
        for (int c = 0; c < NI; ++c) x[t * NI + c] = 1e-3 * sin(0.01 * t * (c + 1) + c);
    double next = now_ns() + period;
    for (long i = 0; i < n; ++i) {
        while (now_ns() < next - period) {
        }
        double t0 = now_ns();
        tm_pipeline_step(h, x + (i & 1023) * NI, NI, out, NO);
        double t1 = now_ns();
        lat[i] = t1 - t0;
        overruns += t1 > next;
        next += period;
    }
    qsort(lat, (size_t)n, sizeof(double), cmp_double);
    if (n > 0)
        printf("latency_ns %.0f %.0f %.0f %.0f\n", lat[n / 2], lat[(long)(0.99 * (n - 1))], lat[(long)(0.999 * (n - 1))],
               lat[n - 1]);
    printf("overruns %ld\n", overruns);
    free(lat);
    tm_pipeline_destroy(h);
}

int main(int argc, char** argv) {
    make_weights();
    run_checks(64, 0);
    run_checks(32, 0);
    run_checks(64, 32);
    if (argc > 1) {
        run_timing(atol(argv[1]), 64, 0);
        run_timing(atol(argv[1]), 32, 0);
        run_timing(atol(argv[1]), 64, 32);
    }
    if (argc > 2) run_paced(atof(argv[2]));
    if (failures) {
        fprintf(stderr, "%d checks failed\n", failures);
        return 1;
    }
    printf("ok\n");
    return 0;
}
