/* Threads on the C ABI (tm.h), meant to run under ThreadSanitizer
 * (tests/run_sanitizers.py --thread): in each round two threads step the same
 * handle (one at a time may: the other gets TM_ERR_BUSY), a third reads its
 * status, a fourth steps a handle of its own, and the main thread destroys the
 * shared handle while they run. Every thread must end with TM_ERR_HANDLE on the
 * shared handle, statuses must be consistent and never go back, and the ticks
 * counted must equal the ticks the steppers were told were taken. Prints "ok".
 */
#define _GNU_SOURCE
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "tm.h"

#define R 2
#define H 4
#define NI (4 * R)
#define NO (2 + 3 * R)
#define ROUNDS 12

static double w1[H * 5], b1[H], w2[2 * H], b2[2];
static const double mean[4] = {0.0, 0.0, 0.0, 0.0};
static const double gain[4] = {2.0, 2.0, 0.5, 0.5};
static const double sos_v[6] = {0.0675, 0.1349, 0.0675, 1.0, -1.1430, 0.4128};

static atomic_int failures;
#define CHECK(cond)                                                                \
    do {                                                                           \
        if (!(cond)) {                                                             \
            fprintf(stderr, "%s:%d: check failed: %s\n", __FILE__, __LINE__, #cond); \
            atomic_fetch_add(&failures, 1);                                        \
        }                                                                          \
    } while (0)

static tm_pipeline create(void) {
    tm_config c;
    tm_config_init(&c);
    for (int i = 0; i < H * 5; ++i) w1[i] = 0.1 * ((i * 7) % 11 - 5);
    for (int i = 0; i < H; ++i) b1[i] = 0.05 * i;
    for (int i = 0; i < 2 * H; ++i) w2[i] = 0.2 * ((i * 3) % 5 - 2);
    c.n_ridges = R;
    c.sos_v = sos_v;
    c.n_sos_v = 1;
    c.n_hidden = H;
    c.w1 = w1;
    c.b1 = b1;
    c.w2 = w2;
    c.b2 = b2;
    c.input_mean = mean;
    c.input_gain = gain;
    c.weights_fs = 1000.0;
    tm_controller_defaults(TM_CONTROLLER_VELOCITY, &c.controller);
    tm_pipeline h = 0;
    CHECK(tm_pipeline_create(&c, &h) == TM_OK);
    return h;
}

typedef struct {
    tm_pipeline h;
    long taken;     /* ticks the library said it took (TM_OK or TM_REJECTED) */
    long busy;      /* TM_ERR_BUSY answers */
    int last;       /* the last status code */
    int own;        /* 1: the handle is this thread's, run a fixed number of ticks */
} stepper;

static void* step_loop(void* arg) {
    stepper* s = (stepper*)arg;
    double x[NI], out[NO], xb[8 * NI], ob[8 * NO];
    for (long t = 0;; ++t) {
        for (int c = 0; c < NI; ++c) x[c] = 0.3 * sin(0.01 * (double)t + c);
        if (t % 50 == 7) x[t % NI] = NAN;
        int rc;
        if (t % 4 == 3) {
            for (int k = 0; k < 8; ++k) memcpy(xb + k * NI, x, sizeof x);
            size_t nrej = 0;
            rc = tm_pipeline_process_block(s->h, xb, 8, NI, ob, NO, NULL, &nrej);
            if (rc == TM_OK) s->taken += 8;
        } else {
            rc = tm_pipeline_step(s->h, x, NI, out, NO);
            if (rc == TM_OK || rc == TM_REJECTED) {
                s->taken += 1;
                for (int k = 0; k < NO; ++k) CHECK(isfinite(out[k]));
            }
        }
        s->busy += rc == TM_ERR_BUSY;
        s->last = rc;
        CHECK(rc == TM_OK || rc == TM_REJECTED || rc == TM_ERR_BUSY || rc == TM_ERR_HANDLE);
        if (rc == TM_ERR_HANDLE) break;
        if (s->own && t == 20000) break;
    }
    return NULL;
}

typedef struct {
    tm_pipeline h;
    long reads;
    int last;
} reader;

static void* read_loop(void* arg) {
    reader* r = (reader*)arg;
    uint64_t prev = 0;
    for (;;) {
        tm_pipeline_status st;
        st.struct_size = sizeof st;
        const int rc = tm_pipeline_get_status(r->h, &st);
        r->last = rc;
        if (rc != TM_OK) break;
        ++r->reads;
        CHECK(st.ticks >= prev);
        CHECK(st.rejected == st.nonfinite + st.out_of_range + st.overflow);
        CHECK(st.rejected <= st.ticks);
        CHECK(isfinite(st.position) && isfinite(st.velocity));
        prev = st.ticks;
    }
    return NULL;
}

int main(void) {
    long busy_total = 0;
    for (int round = 0; round < ROUNDS; ++round) {
        const tm_pipeline shared = create(), own = create();
        stepper a = {shared, 0, 0, 0, 0}, b = {shared, 0, 0, 0, 0}, c = {own, 0, 0, 0, 1};
        reader q = {shared, 0, 0};
        pthread_t ta, tb, tc, tq;
        pthread_create(&ta, NULL, step_loop, &a);
        pthread_create(&tb, NULL, step_loop, &b);
        pthread_create(&tc, NULL, step_loop, &c);
        pthread_create(&tq, NULL, read_loop, &q);
        struct timespec pause = {0, 2000000L + 1000000L * round};
        nanosleep(&pause, NULL);
        tm_pipeline_status st;
        st.struct_size = sizeof st;
        CHECK(tm_pipeline_get_status(shared, &st) == TM_OK);
        CHECK(tm_pipeline_destroy(shared) == TM_OK); /* while a, b and q are inside calls */
        pthread_join(ta, NULL);
        pthread_join(tb, NULL);
        pthread_join(tq, NULL);
        pthread_join(tc, NULL);
        CHECK(a.last == TM_ERR_HANDLE && b.last == TM_ERR_HANDLE && q.last == TM_ERR_HANDLE);
        CHECK(tm_pipeline_destroy(shared) == TM_ERR_HANDLE);
        CHECK(st.ticks <= (uint64_t)(a.taken + b.taken));
        /* the handle of its own was never disturbed */
        CHECK(c.busy == 0 && c.last != TM_ERR_HANDLE);
        st.struct_size = sizeof st;
        CHECK(tm_pipeline_get_status(own, &st) == TM_OK);
        CHECK((long)st.ticks == c.taken);
        CHECK(tm_pipeline_destroy(own) == TM_OK);
        busy_total += a.busy + b.busy;
    }
    printf("busy %ld\n", busy_total);
    if (atomic_load(&failures)) return 1;
    printf("ok\n");
    return 0;
}
