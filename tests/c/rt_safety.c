/* Real-time safety of the tick path of the C ABI (tm.h), run under the
 * interposer rt_counter.c (LD_PRELOAD): with counting on, it steps 2e5 ticks,
 * 5e4 ticks in blocks, reads the status 1e3 times and the features, and hits
 * every kind of rejected tick (NaN, Inf, out of range, an overflowing update) and
 * the error paths (wrong size, NULL, a dead handle, a busy handle). Prints
 *
 *   alloc <n> lock <n> yield <n> ticks <n> rejected <n> nonfinite <n> out_of_range <n> overflow <n>
 *
 * and exits 0 when the pipeline behaved as expected (the counts are judged by the
 * caller, tests/test_rt_safety.py). "calibration alloc <a> lock <l>" is printed
 * first: one malloc and one mutex lock made on purpose while counting, so a
 * missing interposer cannot pass for a clean run. With the argument "bank" the
 * pipelines run the filter-bank detector (detector_kind 1, ABI 6) instead of the
 * paper's net.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tm.h"

#define R 6
#define H 16
#define NI (4 * R)
#define NO (2 + 3 * R)
#define BLOCK 50

#define NF_BANK 17 /* 4 rates + 2 x 4 low-passes + 2 |d| low-passes + load, press, peak */
static double w1[H * (NF_BANK + 1)], b1[H], w2[2 * H], b2[2];
static const double mean[NF_BANK] = {0.0};
static const double gain[NF_BANK] = {2.0, 2.0, 0.5, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0,
                                     1.0, 1.0, 1.0, 1.0, 1.0, 10.0, 10.0, 10.0};
static const double lp_taus[4] = {0.004, 0.016, 0.064, 0.256};
static const double abs_taus[2] = {0.016, 0.064};
static const double sos_v[6] = {0.0675, 0.1349, 0.0675, 1.0, -1.1430, 0.4128};
static const double sos_u[12] = {0.2, 0.0, -0.2, 1.0, -0.5, 0.1, 1.0, 0.5, 0.0, 1.0, -0.3, 0.0};

typedef void (*enable_fn)(int);
typedef void (*get_fn)(long*, long*, long*);
typedef void (*clear_fn)(void);
static enable_fn counter_enable;
static get_fn counter_get;
static clear_fn counter_clear;

static int failures = 0;
#define CHECK(cond)                                                                                 \
    do {                                                                                            \
        if (!(cond)) {                                                                              \
            fprintf(stderr, "%s:%d: check failed: %s (last error: %s)\n", __FILE__, __LINE__, #cond, \
                    tm_last_error());                                                               \
            ++failures;                                                                             \
        }                                                                                           \
    } while (0)

static void make_config(tm_config* c, double limit, int bank) {
    const int nw = H * (bank ? NF_BANK + 1 : 5);
    unsigned s = 12345u;
    for (int i = 0; i < nw; ++i) { s = s * 1103515245u + 12345u; w1[i] = ((s >> 8) % 2001 - 1000) / 500.0; }
    for (int i = 0; i < H; ++i) { s = s * 1103515245u + 12345u; b1[i] = ((s >> 8) % 2001 - 1000) / 1000.0; }
    for (int i = 0; i < 2 * H; ++i) { s = s * 1103515245u + 12345u; w2[i] = ((s >> 8) % 2001 - 1000) / 300.0; }
    b2[0] = -1.0;
    b2[1] = -0.5;
    tm_config_init(c);
    c->sos_v = sos_v;
    c->n_sos_v = 1;
    c->sos_u = sos_u;
    c->n_sos_u = 2;
    c->v_limit = limit;
    c->u_limit = limit;
    c->n_hidden = H;
    c->w1 = w1;
    c->b1 = b1;
    c->w2 = w2;
    c->b2 = b2;
    c->input_mean = mean;
    c->input_gain = gain;
    c->weights_fs = 1000.0;
    c->activation = 1;
    tm_controller_defaults(TM_CONTROLLER_VELOCITY, &c->controller);
    c->controller.shear_gain = 1e-3;
    if (bank) {
        c->detector_kind = 1;
        c->bank_n_lp = 4;
        c->bank_lp_taus = lp_taus;
        c->bank_n_abs = 2;
        c->bank_abs_taus = abs_taus;
        c->bank_load_tau = 0.5;
        c->bank_peak_tau = 2.0;
    }
}

/* Sample t of a smooth test signal, with bad samples of every kind sprinkled in. */
static void sample(long t, double* x, long* expect_bad) {
    for (int c = 0; c < NI; ++c) x[c] = 0.5 * sin(0.003 * (double)t * (c + 1) + c);
    switch (t % 997) {
        case 10: x[t % NI] = NAN; ++expect_bad[0]; break;
        case 20: x[(t + 1) % NI] = -INFINITY; ++expect_bad[0]; break;
        case 30: x[(t + 2) % NI] = 99.0; ++expect_bad[1]; break;
        case 40: x[(t + 3) % NI] = 1.7e308; ++expect_bad[1]; break;
        default: break;
    }
}

int main(int argc, char** argv) {
    const int bank = argc > 1 && strcmp(argv[1], "bank") == 0;
    counter_enable = (enable_fn)dlsym(RTLD_DEFAULT, "rt_counter_enable");
    counter_get = (get_fn)dlsym(RTLD_DEFAULT, "rt_counter_get");
    counter_clear = (clear_fn)dlsym(RTLD_DEFAULT, "rt_counter_clear");
    if (!counter_enable || !counter_get || !counter_clear) {
        fprintf(stderr, "run with LD_PRELOAD=librt_counter.so\n");
        return 2;
    }
    tm_config cfg;
    tm_pipeline h = 0, h_over = 0, dead = 0;
    make_config(&cfg, 15.0, bank);
    CHECK(tm_pipeline_create(&cfg, &h) == TM_OK);
    make_config(&cfg, DBL_MAX, bank);  /* no sample limit: only the overflow guard stands */
    CHECK(tm_pipeline_create(&cfg, &h_over) == TM_OK);
    CHECK(tm_pipeline_create(&cfg, &dead) == TM_OK);
    CHECK(tm_pipeline_destroy(dead) == TM_OK);

    static double xb[BLOCK * NI], ob[BLOCK * NO];
    double x[NI], out[NO], feat[R * 4];
    unsigned char acc[BLOCK];
    size_t nrej = 0;
    long expect_bad[2] = {0, 0}; /* nonfinite, out_of_range */
    long overflow_sent = 0; /* rejected ticks of h_over (all must be overflows) */
    tm_pipeline_status st;
    long a = 0, l = 0, y = 0;

    /* Calibration: the interposer sees a malloc and a mutex lock made on purpose. */
    pthread_mutex_t m = PTHREAD_MUTEX_INITIALIZER;
    counter_clear();
    counter_enable(1);
    void* volatile p = malloc(16);
    pthread_mutex_lock(&m);
    counter_enable(0);
    pthread_mutex_unlock(&m);
    free(p);
    counter_get(&a, &l, &y);
    printf("calibration alloc %ld lock %ld\n", a, l);

    counter_clear();
    counter_enable(1);
    /* 2e5 single ticks */
    for (long t = 0; t < 200000; ++t) {
        sample(t, x, expect_bad);
        const int rc = tm_pipeline_step(h, x, NI, out, NO);
        CHECK(rc == TM_OK || rc == TM_REJECTED);
    }
    /* 5e4 ticks in blocks */
    for (long b = 0; b < 50000 / BLOCK; ++b) {
        for (int k = 0; k < BLOCK; ++k) sample(200000 + b * BLOCK + k, xb + k * NI, expect_bad);
        CHECK(tm_pipeline_process_block(h, xb, BLOCK, NI, ob, NO, acc, &nrej) == TM_OK);
    }
    /* 1e3 status reads, features */
    for (int i = 0; i < 1000; ++i) {
        st.struct_size = sizeof st;
        CHECK(tm_pipeline_get_status(h, &st) == TM_OK);
        CHECK(tm_pipeline_features(h, feat, R * 4) == TM_OK);
    }
    /* overflowing updates: finite samples far beyond any state's range */
    for (long t = 0; t < 2000; ++t) {
        long ignored[2] = {0, 0};
        sample(t, x, ignored);
        for (int c = 0; c < NI; ++c) x[c] = isfinite(x[c]) ? x[c] : 0.0;
        /* L strips at +max, R strips at -max for 3 ticks: the filters stay finite,
         * the L-R asymmetry summed over the ridges does not */
        if (t % 100 >= 50 && t % 100 < 53)
            for (int r = 0; r < R; ++r) {
                x[2 * r] = DBL_MAX;
                x[2 * r + 1] = -DBL_MAX;
            }
        const int rc = tm_pipeline_step(h_over, x, NI, out, NO);
        CHECK(rc == TM_OK || rc == TM_REJECTED);
        overflow_sent += rc == TM_REJECTED;
        for (int k = 0; k < NO; ++k) CHECK(isfinite(out[k]));
    }
    /* error paths */
    CHECK(tm_pipeline_step(h, x, NI - 1, out, NO) == TM_ERR_SIZE);
    CHECK(tm_pipeline_step(h, NULL, NI, out, NO) == TM_ERR_NULL);
    CHECK(tm_pipeline_step(dead, x, NI, out, NO) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_step(0, x, NI, out, NO) == TM_ERR_HANDLE);
    CHECK(tm_pipeline_reset(h_over, NAN) == TM_ERR_ARGUMENT);
    CHECK(tm_pipeline_set_position(h_over, INFINITY) == TM_ERR_ARGUMENT);
    CHECK(tm_pipeline_features(h, feat, 3) == TM_ERR_SIZE);
    st.struct_size = 1;
    CHECK(tm_pipeline_get_status(h, &st) == TM_ERR_VERSION);
    counter_enable(0);
    counter_get(&a, &l, &y);

    st.struct_size = sizeof st;
    CHECK(tm_pipeline_get_status(h, &st) == TM_OK);
    CHECK(st.ticks == 250000);
    CHECK((long)st.nonfinite == expect_bad[0]);
    CHECK((long)st.out_of_range == expect_bad[1]);
    CHECK(st.overflow == 0);
    tm_pipeline_status so;
    so.struct_size = sizeof so;
    CHECK(tm_pipeline_get_status(h_over, &so) == TM_OK);
    CHECK(overflow_sent > 0);
    CHECK((long)so.overflow == overflow_sent);
    CHECK(so.rejected == so.overflow);
    CHECK(so.last_reason == TM_REASON_OVERFLOW);
    printf("alloc %ld lock %ld yield %ld ticks %llu rejected %llu nonfinite %llu out_of_range %llu overflow %llu\n",
           a, l, y, (unsigned long long)st.ticks, (unsigned long long)st.rejected,
           (unsigned long long)st.nonfinite, (unsigned long long)st.out_of_range, (unsigned long long)so.overflow);
    CHECK(tm_pipeline_destroy(h) == TM_OK);
    CHECK(tm_pipeline_destroy(h_over) == TM_OK);
    return failures ? 1 : 0;
}
