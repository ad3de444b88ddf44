/* tm.h - plain C interface of the tactile-mirror real-time pipeline.
 *
 * One pipeline turns, once per tick, the sampled PVDF circuit outputs of the pad's
 * ridges into slip-detector outputs and a stage command:
 *
 *   x   = [v_L0, v_R0, v_L1, v_R1, ..., (u_L0, u_R0, ... when use_u), (force, N, when force_input)]
 *         (n_inputs)
 *   out = [x_cmd (m), v_cmd (m/s), y_slip_0, y_non_0, y_pred_0, y_slip_1, ...]
 *                                                          (n_outputs = 2 + 3 n_ridges)
 *
 * Usage:
 *
 *   tm_config cfg;
 *   tm_config_init(&cfg);                 // defaults, struct_size and abi_version
 *   cfg.n_ridges = 6; cfg.fs = 1000.0; ...  // filters, detector weights, controller
 *   tm_pipeline h;
 *   if (tm_pipeline_create(&cfg, &h) != TM_OK) puts(tm_last_error());
 *   int rc = tm_pipeline_step(h, x, n_inputs, out, n_outputs);   // TM_OK or TM_REJECTED
 *   tm_pipeline_destroy(h);
 *
 * Rules:
 * - Every function returns a tm_status code (TM_OK = 0, TM_REJECTED = 1 is a rejected
 *   tick, negative values are errors) and never aborts the process. On an error
 *   nothing changes and tm_last_error() (per thread) says what was wrong.
 * - Handles are numbers, not pointers: 0, a destroyed handle or any other value
 *   that was not returned by tm_pipeline_create gives TM_ERR_HANDLE.
 * - tm_pipeline_step, tm_pipeline_process_block, tm_pipeline_get_status and
 *   tm_pipeline_features allocate nothing, take no lock and make no system call
 *   (their error paths included): call them from the real-time thread.
 * - Threads: one thread at a time drives a handle. A call of step, process_block,
 *   features, reset, set_position or time_step_ns that finds another thread inside
 *   one of them on the same handle returns TM_ERR_BUSY at once (it never waits).
 *   tm_pipeline_get_status and tm_pipeline_sizes may be called from any thread at
 *   any time: the status is the one published at the end of the last call that
 *   changed it, never a torn mix. Different handles are independent.
 * - tm_pipeline_destroy may be called from any thread, even while another thread is
 *   inside a call on the same handle: the handle is dead at once (every later call
 *   gets TM_ERR_HANDLE) and destroy returns after the calls already in flight on it
 *   have returned; only then is the pipeline freed. create and destroy take a
 *   process-wide lock (they are not real-time calls).
 * - A tick is accepted only if its samples are finite and within v_limit / u_limit
 *   and every state it updates (filters, detector, controller) stays finite;
 *   otherwise the state is what it was before the tick, the tick is counted in the
 *   status with its reason (nonfinite, out_of_range, overflow) and TM_REJECTED is
 *   returned.
 * - Structures carry their own size (struct_size), and new fields are only ever
 *   appended. tm_pipeline_get_status fills the first struct_size bytes, so a program
 *   built against an older tm.h gets the fields it knows. tm_pipeline_create accepts
 *   a tm_config whose struct_size is at least that of ABI 2 (the first with
 *   struct_size) and at most this header's; fields beyond a shorter struct_size take
 *   their tm_config_init defaults. abi_version must lie in 2..TM_ABI_VERSION (the
 *   tm_config layout only grew at its end since 2).
 *
 * The library is shipped in the tactile_mirror Python wheel next to this header;
 * tactile_mirror.loop.capi.library_path() gives its path.
 */
#ifndef TACTILE_MIRROR_TM_H
#define TACTILE_MIRROR_TM_H

#include <stddef.h>
#include <stdint.h>

#if defined(_WIN32)
#define TM_API __declspec(dllexport)
#else
#define TM_API __attribute__((visibility("default")))
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* ABI version: incremented on any incompatible change of this header or of the
 * library's behaviour. 3: TM_ERR_BUSY, the overflow rejection and its status fields,
 * finite default limits (+inf refused), tm_controller_defaults and the controller
 * defaults shared with the Python library. 4: the velocity law's shear_integral
 * and rate_gain (appended to tm_controller_params, the last member of tm_config).
 * 5: slip_confirm, slip_min_asym, shear_weights. 6: the filter-bank detector
 * (detector_kind and the bank's time constants, appended to tm_config). 7: the
 * controller's planner_decel (appended to tm_config: tm_controller_params is no longer
 * its last member), and the command leads a planning stage's target when it is > 0.
 * 8: bank_knee (appended to tm_config): the filter-bank net's compressed inputs.
 * 9: bank_pad_mean (appended to tm_config): the filter-bank net that also reads the pad's mean.
 * 10: force_limit, force_input (appended to tm_config): a load cell's force as the last input,
 * the controller's shear signal. */
#define TM_ABI_VERSION 10

typedef enum tm_status_code {
    TM_OK = 0,
    TM_REJECTED = 1,        /* step: the tick's samples were rejected (non-finite or out of range) */
    TM_ERR_NULL = -1,       /* a required pointer is NULL */
    TM_ERR_HANDLE = -2,     /* not a live pipeline handle */
    TM_ERR_ARGUMENT = -3,   /* invalid configuration or argument value */
    TM_ERR_SIZE = -4,       /* an array size does not match the pipeline */
    TM_ERR_FS = -5,         /* detector weights made for another sample rate */
    TM_ERR_VERSION = -6,    /* struct_size / abi_version not supported */
    TM_ERR_MEMORY = -7,     /* out of memory or out of handles */
    TM_ERR_INTERNAL = -8,   /* unexpected failure (a bug: please report) */
    TM_ERR_BUSY = -9        /* the handle is being driven by another thread right now */
} tm_status_code;

typedef enum tm_controller_kind {
    TM_CONTROLLER_NONE = 0,     /* detection only: the command stays at its start position */
    TM_CONTROLLER_PAPER = 1,    /* displacement proportional to y_pred above the threshold */
    TM_CONTROLLER_VELOCITY = 2  /* velocity ramp with deadband, speed/acceleration/travel limits */
} tm_controller_kind;

typedef struct tm_controller_params {
    int32_t kind;            /* tm_controller_kind */
    double threshold;        /* y_pred threshold (paper) / start of the speed ramp (velocity), [0, 1) */
    double gain;             /* paper: m/s of target motion per unit y_pred, >= 0 */
    double y_full;           /* velocity: y_pred giving full speed, (threshold, 1] */
    double v_max;            /* velocity: m/s, > 0 */
    double a_max;            /* velocity: m/s^2, > 0 */
    double x_min, x_max;     /* travel limits, m, x_min <= 0 <= x_max, x_min < x_max */
    double direction_sign;   /* +1 or -1: stage direction for a positive L-R asymmetry */
    double asym_tau;         /* s, > 0: leak of the L/R asymmetry integrator */
    double asym_deadband;    /* >= 0: |asymmetry| below this keeps the previous direction */
    double shear_gain;       /* velocity: m/s per unit of asymmetry (shear feedback), >= 0; 0 = off */
    double arm_delay;        /* s after a reset during which the stage holds; then the asymmetry is tared */
    double ramp_gain;        /* velocity: share of v_max commanded by the y_pred ramp, >= 0; 0 = no ramp term */
    double pred_boost;       /* velocity: shear gain x (1 + pred_boost * ramp(y_pred)), >= 0 */
    double slip_hold;        /* s, >= 0: on detected slip hold the stage, re-tare this long after (0 = off) */
    /* ABI 4 (appended: tm_config grows at its end, a shorter struct_size keeps these at their defaults) */
    double shear_integral;   /* velocity: 1/s, >= 0: integral of the shear feedback (type-2 loop); 0 = off */
    double rate_gain;        /* velocity: m/s per unit of L-R stress rate (relative-velocity feedback), >= 0 */
    /* ABI 5 (appended) */
    double slip_confirm;     /* s, >= 0: a detected slip starts the slip guard once it lasted this long (0 = at once) */
    double slip_min_asym;    /* >= 0: a detected slip starts the slip guard only while |asymmetry| >= this (0 = always) */
} tm_controller_params;

typedef struct tm_config {
    uint32_t struct_size;    /* sizeof(tm_config), set by tm_config_init */
    uint32_t abi_version;    /* TM_ABI_VERSION, set by tm_config_init */
    int32_t precision;       /* 64: double arithmetic (default), 32: float */
    int32_t detector_precision;  /* 0: as precision; 32 with precision 64: double filters, float detector */
    int32_t n_ridges;        /* ridges in use, 1..64 */
    double fs;               /* sample rate, Hz */
    int32_t use_u;           /* 1: u_out is sampled; 0: digital differentiator on the rate */
    /* Second-order sections, rows (b0, b1, b2, a0, a1, a2), row-major. */
    const double* sos_v;     /* v_out -> stress rate; n_sos_v = 0: raw v_out is the feature */
    int32_t n_sos_v;
    const double* sos_u;     /* u_out -> 2nd-order rate (use_u); n_sos_u = 0: raw u_out */
    int32_t n_sos_u;
    const double* sos_diff;  /* rate -> 2nd-order rate (use_u = 0; at least one section) */
    int32_t n_sos_diff;
    double v_limit, u_limit; /* |sample| above the limit (V): the tick is rejected; finite, > 0;
                              * default 15 V, the swing of a +-15 V front end */
    /* Detector (Jordan MLP, nf inputs + y_pred feedback, H hidden units; nf = 4, the
     * stress rates, unless detector_kind (ABI 6) selects the filter bank). */
    int32_t n_hidden;
    const double* w1;        /* (H, nf + 1) row-major */
    const double* b1;        /* (H) */
    const double* w2;        /* (2, H) row-major: rows y_slip, y_pred */
    const double* b2;        /* (2) */
    const double* input_mean;  /* (nf) */
    const double* input_gain;  /* (nf): inputs are (x - mean) * gain */
    double weights_fs;       /* Hz the detector was trained for: must equal fs */
    int32_t activation;      /* 0 exact sigmoid, 1 fast polynomial sigmoid */
    double slip_threshold;   /* y_slip >= this counts as slip in the status, (0, 1) */
    int64_t max_hold_ticks;  /* consecutive rejected ticks before the fault state, >= 0 */
    tm_controller_params controller;
    /* ABI 5 (appended) */
    const double* shear_weights;  /* (n_ridges, 2) row-major or NULL: the controller's shear signal is
                                   * sum_r w[r][0] rate_L + w[r][1] rate_R; NULL: +1, -1 (L - R) */
    /* ABI 6 (appended) */
    int32_t detector_kind;   /* 0: the paper's net on [rate_L, rate_R, rate2_L, rate2_R] (nf = 4);
                              * 1: the filter-bank net: those plus, per ridge, low-passes of the
                              * shear and normal rates, of |shear rate|, the shear and normal load
                              * and the peak load (nf = 4 + 2 bank_n_lp + bank_n_abs + 3; the
                              * weights file of kind "jordan_bank" holds them) */
    int32_t bank_n_lp;       /* 1..8 low-pass time constants (s) in bank_lp_taus */
    const double* bank_lp_taus;
    int32_t bank_n_abs;      /* 0..8 time constants (s) of the |shear rate| low-passes */
    const double* bank_abs_taus;
    double bank_load_tau;    /* s: leak of the load integrals */
    double bank_peak_tau;    /* s: decay of the peak load */
    /* ABI 7 (appended) */
    double planner_decel;    /* controller (both laws), m/s^2, >= 0: the stage plans a braking move to each
                              * target at this deceleration (a point-to-point move command; its a_max); the
                              * command then leads the law's position by the braking distance
                              * v^2 / (2 planner_decel) - |v| / (2 fs), so that the planned set point moves at the
                              * law's speed. 0 (default): the stage follows the command (streamed set points) */
    /* ABI 8 (appended) */
    const double* bank_knee; /* (nf) or NULL (default): with detector_kind 1, every bank input x is first
                              * compressed to sign(x) log(1 + |x| / knee) (the weights file of kind
                              * "jordan_bank" holds the knees in its bank's "knee", when it has them) */
    /* ABI 9 (appended) */
    int32_t bank_pad_mean;   /* 0 (default) or 1: with detector_kind 1, the net also reads the mean of the bank's
                              * features over the ridges (the same for every ridge), after each ridge's own: its
                              * inputs (w1's columns, input_mean, input_gain, bank_knee) are twice the features
                              * (the bank's "pad_mean" in a weights file of kind "jordan_bank") */
    /* ABI 10 (appended; force_limit first: an ABI-9 struct ends with 4 bytes of padding after
     * bank_pad_mean, and no ABI-10 field may lie there) */
    double force_limit;      /* N, in (0, 1e6] (default 100): |force| above it rejects the tick, as a bad voltage */
    int32_t force_input;     /* 0 (default) or 1: one more input after the voltages, the pad's tangential force
                              * in N (a load cell under the pad, or the stage's force readout); the controller's
                              * shear signal is then the force's change per tick times fs (N/s), not the strips'
                              * rates: a force has no partial-slip phantom (docs/loop.md). n_inputs grows by 1 */
} tm_config;

typedef struct tm_pipeline_status {
    uint32_t struct_size;    /* set by the caller to sizeof(tm_pipeline_status) */
    uint64_t ticks;          /* ticks stepped (accepted + rejected) */
    uint64_t rejected;
    uint64_t nonfinite;      /* rejected ticks with a NaN or Inf sample */
    uint64_t out_of_range;   /* rejected ticks with a finite sample beyond its limit */
    int64_t last_bad_tick;   /* -1 if none */
    int32_t last_bad_channel;
    uint32_t consecutive_rejected;
    int32_t fault;           /* 1: more than max_hold_ticks consecutive rejections, the stage stops */
    int32_t slip;            /* 1: max y_slip >= slip_threshold at the last accepted tick */
    int32_t at_limit;        /* 1: the law's position is on a travel limit (the led command may reach one first) */
    double position;         /* the command sent to the stage (the law's position, led with planner_decel), m */
    double velocity;         /* commanded velocity, m/s */
    /* ABI 3 */
    uint64_t overflow;       /* rejected ticks whose update would have made a state non-finite */
    int32_t last_reason;     /* tm_reject_reason of the last rejected tick */
} tm_pipeline_status;

typedef enum tm_reject_reason {
    TM_REASON_NONE = 0,         /* no tick rejected yet */
    TM_REASON_NONFINITE = 1,    /* a NaN or Inf sample (last_bad_channel: the first) */
    TM_REASON_OUT_OF_RANGE = 2, /* a finite sample beyond v_limit / u_limit */
    TM_REASON_OVERFLOW = 3      /* valid samples, but a filter, detector or controller state would become
                                 * non-finite (last_bad_channel -1) */
} tm_reject_reason;

typedef uint64_t tm_pipeline;  /* 0 is never a valid handle */

TM_API int32_t tm_abi_version(void);
TM_API const char* tm_version_string(void);
TM_API const char* tm_status_name(int32_t code);
/* The message of the last error on the calling thread ("" if none). */
TM_API const char* tm_last_error(void);

/* Fill cfg with defaults: 6 ridges, 1 kHz, use_u, no filters, limits 15 V, no detector
 * weights (w1 ... must be set), no controller. Writes exactly `size` bytes (the size of
 * tm_config as the caller's header declares it), sets struct_size to it and abi_version to
 * the newest ABI whose struct fits; size must lie in the range tm_pipeline_create accepts
 * (TM_ERR_VERSION otherwise, nothing written). */
TM_API int32_t tm_config_init_sized(tm_config* cfg, uint32_t size);
/* tm_config_init(cfg) is tm_config_init_sized(cfg, sizeof(tm_config)) (the macro below):
 * a program built against this header fills exactly its own struct, whatever later
 * library it runs against. The function of that name is what programs built against the
 * headers of ABI 6 and earlier call: it fills an ABI-6 struct (struct_size up to
 * planner_decel, abi_version 6) and writes no byte beyond it. (Programs built against
 * ABI 5 or earlier that call it must be rebuilt: their struct is shorter still.) */
TM_API int32_t tm_config_init(tm_config* cfg);
#define tm_config_init(cfg) tm_config_init_sized((cfg), (uint32_t)sizeof(tm_config))
/* The defaults of every parameter with kind TM_CONTROLLER_NONE. */
TM_API int32_t tm_controller_init(tm_controller_params* params);
/* The defaults of a law (tm_controller_kind): the same numbers as the Python library's
 * PaperController() / VelocityController(); kind is set to the given law. */
TM_API int32_t tm_controller_defaults(int32_t kind, tm_controller_params* params);

TM_API int32_t tm_pipeline_create(const tm_config* cfg, tm_pipeline* out);
TM_API int32_t tm_pipeline_destroy(tm_pipeline h);

TM_API int32_t tm_pipeline_sizes(tm_pipeline h, size_t* n_inputs, size_t* n_outputs);
/* One tick. Returns TM_OK, TM_REJECTED (out holds the held outputs) or an error. */
TM_API int32_t tm_pipeline_step(tm_pipeline h, const double* x, size_t n_x, double* out, size_t n_out);
/* n_ticks ticks, x row-major (n_ticks, n_inputs), out row-major (n_ticks, n_outputs);
 * accepted (may be NULL) gets 1/0 per tick; n_rejected (may be NULL) the count.
 * Identical to n_ticks calls of tm_pipeline_step. */
TM_API int32_t tm_pipeline_process_block(tm_pipeline h, const double* x, size_t n_ticks, size_t n_x,
                                         double* out, size_t n_out, uint8_t* accepted, size_t* n_rejected);
/* Features of the last accepted tick, (n_ridges, 4): rate_L, rate_R, rate2_L, rate2_R. */
TM_API int32_t tm_pipeline_features(tm_pipeline h, double* f, size_t n_f);
/* Back to rest with the command at x0 (m); counters cleared. */
TM_API int32_t tm_pipeline_reset(tm_pipeline h, double x0);
/* Tell the controller where the stage is, m. */
TM_API int32_t tm_pipeline_set_position(tm_pipeline h, double x);
/* Any thread, any time (see Rules). status->struct_size must be set by the caller. */
TM_API int32_t tm_pipeline_get_status(tm_pipeline h, tm_pipeline_status* status);
/* Mean ns per tick measured inside the library (state restored afterwards). */
TM_API int32_t tm_pipeline_time_step_ns(tm_pipeline h, int64_t n_iter, double* ns);

#ifdef __cplusplus
}
#endif

#endif /* TACTILE_MIRROR_TM_H */
