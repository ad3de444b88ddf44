// The C ABI of tm.h over MirrorPipeline<T> (pipeline.hpp).
//
// Handles index a fixed table of slots; a handle carries the slot and the slot's
// generation, so 0, stale (destroyed) and made-up handles are recognised without
// ever dereferencing them. Nothing here lets an exception or an abort escape.
//
// Lifetime and threads. A call that drives a pipeline (step, process_block,
// features, reset, set_position, time_step_ns) claims its slot's owner word, which
// holds the slot's generation and a busy bit, with one compare-exchange from
// (generation of the handle, free) to (same, busy): it fails for a stale handle
// (another generation) and for a handle another thread is driving (busy), so
// cross-thread use is refused and nothing ever waits. Releasing is one store. The
// readers (get_status, sizes) count themselves in the slot's reader counter
// instead. Every claim or count happens before the call checks the generation, and
// destroy bumps the generation before it waits for the owner word to be free (it
// then moves it to the new generation) and for the readers to leave (all
// sequentially consistent). So a call either sees the handle dead, or destroy sees
// the call and frees the pipeline only after it returned. The tick path makes one
// atomic read-modify-write per call.
#include "tm.h"

#include <atomic>
#include <cstdarg>
#include <cstddef>
#include <cstdio>
#include <cstring>
#include <exception>
#include <memory>
#include <mutex>
#include <new>
#include <stdexcept>
#include <thread>

#include "pipeline.hpp"

namespace {

using tactile::MirrorPipeline;
using tactile::PipelineConfig;

thread_local char g_error[512] = "";

int32_t fail(int32_t code, const char* fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    std::vsnprintf(g_error, sizeof g_error, fmt, ap);
    va_end(ap);
    return code;
}

struct Instance {
    std::unique_ptr<MirrorPipeline<double>> d;
    std::unique_ptr<MirrorPipeline<float>> f;
    std::unique_ptr<MirrorPipeline<double, float>> m;
};

constexpr std::uint32_t kSlots = 4096;
struct Slot {
    std::atomic<Instance*> inst{nullptr};
    std::atomic<std::uint32_t> gen{1};
    std::atomic<std::uint64_t> owner{std::uint64_t(1) << 1};  // generation << 1 | busy
    std::atomic<std::uint32_t> readers{0};                    // get_status, sizes in flight
};
Slot g_slots[kSlots];
std::mutex g_table_lock;

// A reading call in flight on a handle: keeps the pipeline alive until it goes out
// of scope.
class Use {
public:
    explicit Use(tm_pipeline h) noexcept {
        const std::uint64_t idx = (h & 0xffffffffu);
        const std::uint32_t gen = std::uint32_t(h >> 32);
        if (idx == 0 || idx > kSlots) return;
        slot_ = &g_slots[idx - 1];
        slot_->readers.fetch_add(1, std::memory_order_seq_cst);
        if (slot_->gen.load(std::memory_order_seq_cst) != gen) return;
        inst_ = slot_->inst.load(std::memory_order_acquire);
    }
    ~Use() {
        if (slot_) slot_->readers.fetch_sub(1, std::memory_order_release);
    }
    Use(const Use&) = delete;
    Use& operator=(const Use&) = delete;
    Instance* get() const noexcept { return inst_; }

private:
    Slot* slot_ = nullptr;
    Instance* inst_ = nullptr;
};

// A driving call in flight: owns the handle (one thread at a time) and keeps the
// pipeline alive until it goes out of scope. status() is TM_OK, TM_ERR_HANDLE or
// TM_ERR_BUSY.
class Drive {
public:
    explicit Drive(tm_pipeline h) noexcept {
        const std::uint64_t idx = (h & 0xffffffffu);
        const std::uint32_t gen = std::uint32_t(h >> 32);
        if (idx == 0 || idx > kSlots) return;
        Slot* slot = &g_slots[idx - 1];
        std::uint64_t word = std::uint64_t(gen) << 1;
#ifdef TM_BENCH_NO_GUARDS  // bench/soak.py's unguarded variant: the generation check only
        if ((word = slot->owner.load(std::memory_order_relaxed)) != std::uint64_t(gen) << 1) {
#else
        if (!slot->owner.compare_exchange_strong(word, word | 1u, std::memory_order_seq_cst,
                                                 std::memory_order_relaxed)) {
#endif
            if ((word >> 1) == gen) status_ = TM_ERR_BUSY;  // else another generation: stale
            return;
        }
#ifndef TM_BENCH_NO_GUARDS
        slot_ = slot;
#endif
        free_word_ = std::uint64_t(gen) << 1;
        // Destroy may have begun (it bumps gen first, then waits for the owner word).
        if (slot->gen.load(std::memory_order_seq_cst) != gen) return;
        inst_ = slot->inst.load(std::memory_order_acquire);
        if (inst_) status_ = TM_OK;
    }
    ~Drive() {
        if (slot_) slot_->owner.store(free_word_, std::memory_order_release);
    }
    Drive(const Drive&) = delete;
    Drive& operator=(const Drive&) = delete;
    Instance* get() const noexcept { return inst_; }
    int32_t status() const noexcept { return status_; }

private:
    Slot* slot_ = nullptr;
    Instance* inst_ = nullptr;
    std::uint64_t free_word_ = 0;
    int32_t status_ = TM_ERR_HANDLE;
};

#define TM_GET(h, inst)                                                                   \
    Use use_(h);                                                                          \
    Instance* inst = use_.get();                                                          \
    if (!inst) return fail(TM_ERR_HANDLE, "handle %llu is not a live pipeline", (unsigned long long)(h))

// The calls that read or change a pipeline's state own it: one thread at a time.
#define TM_DRIVE(h, inst)                                                                           \
    Drive drive_(h);                                                                                \
    Instance* inst = drive_.get();                                                                  \
    if (drive_.status() == TM_ERR_BUSY)                                                             \
        return fail(TM_ERR_BUSY, "handle %llu is being used by another thread", (unsigned long long)(h)); \
    if (!inst) return fail(TM_ERR_HANDLE, "handle %llu is not a live pipeline", (unsigned long long)(h))

template <typename F>
auto with(Instance* in, F&& f) noexcept {
    if (in->d) return f(*in->d);
    if (in->m) return f(*in->m);
    return f(*in->f);
}

// tm_controller_params and ControllerParams hold the same fields, both from
// TM_CONTROLLER_FIELDS (a field missing in tm.h does not compile).
void controller_to_c(const tactile::ControllerParams& d, tm_controller_params* p) {
    p->kind = int32_t(d.kind);
#define TM_TO_C(name, def, laws, doc) p->name = d.name;
    TM_CONTROLLER_FIELDS(TM_TO_C)
#undef TM_TO_C
}

tactile::ControllerParams controller_from_c(const tm_controller_params& p) {
    tactile::ControllerParams c;
    c.kind = tactile::ControllerKind(p.kind);
#define TM_FROM_C(name, def, laws, doc) c.name = p.name;
    TM_CONTROLLER_FIELDS(TM_FROM_C)
#undef TM_FROM_C
    return c;
}

#define TM_STR2(x) #x
#define TM_STR(x) TM_STR2(x)

}  // namespace

extern "C" {

int32_t tm_abi_version(void) { return TM_ABI_VERSION; }

const char* tm_version_string(void) { return "tactile-mirror C ABI " TM_STR(TM_ABI_VERSION) " (pipeline 0.1.0)"; }

const char* tm_status_name(int32_t code) {
    switch (code) {
        case TM_OK: return "TM_OK";
        case TM_REJECTED: return "TM_REJECTED";
        case TM_ERR_NULL: return "TM_ERR_NULL";
        case TM_ERR_HANDLE: return "TM_ERR_HANDLE";
        case TM_ERR_ARGUMENT: return "TM_ERR_ARGUMENT";
        case TM_ERR_SIZE: return "TM_ERR_SIZE";
        case TM_ERR_FS: return "TM_ERR_FS";
        case TM_ERR_VERSION: return "TM_ERR_VERSION";
        case TM_ERR_MEMORY: return "TM_ERR_MEMORY";
        case TM_ERR_INTERNAL: return "TM_ERR_INTERNAL";
        case TM_ERR_BUSY: return "TM_ERR_BUSY";
        default: return "unknown status";
    }
}

const char* tm_last_error(void) { return g_error; }

int32_t tm_controller_init(tm_controller_params* params) {
    if (!params) return fail(TM_ERR_NULL, "params is NULL");
    controller_to_c(tactile::default_controller(tactile::ControllerKind::none), params);
    return TM_OK;
}

int32_t tm_controller_defaults(int32_t kind, tm_controller_params* params) {
    if (!params) return fail(TM_ERR_NULL, "params is NULL");
    if (kind < 0 || kind > 2)
        return fail(TM_ERR_ARGUMENT, "kind must be 0 (none), 1 (paper) or 2 (velocity), got %d", int(kind));
    controller_to_c(tactile::default_controller(tactile::ControllerKind(kind)), params);
    return TM_OK;
}

// sizeof(tm_config) in ABI 2, the first ABI with struct_size (and in ABI 3): it ended
// with the controller's slip_hold. Fields are only ever appended since (ABI 4:
// shear_integral and rate_gain at the end of the controller, the end of tm_config;
// ABI 5: slip_confirm at the end of the controller, shear_weights after it; ABI 6:
// detector_kind and the filter bank's time constants; ABI 7: planner_decel, a controller
// parameter kept in tm_config's tail, TM_CONTROLLER_TAIL_FIELDS; ABI 8: bank_knee; ABI 9:
// bank_pad_mean; ABI 10: force_limit, force_input). A struct of ABI 4 ends where slip_confirm
// begins, one of ABI 5 where detector_kind begins, one of ABI 6 where planner_decel begins,
// one of ABI 7 where bank_knee begins, one of ABI 8 where bank_pad_mean begins, one of ABI 9
// where force_limit begins.
constexpr std::size_t kConfigSizeAbi2 = offsetof(tm_config, controller) + offsetof(tm_controller_params, shear_integral);
constexpr std::size_t kConfigSizeAbi4 = offsetof(tm_config, controller) + offsetof(tm_controller_params, slip_confirm);
constexpr std::size_t kConfigSizeAbi5 = offsetof(tm_config, detector_kind);
constexpr std::size_t kConfigSizeAbi6 = offsetof(tm_config, planner_decel);
constexpr std::size_t kConfigSizeAbi7 = offsetof(tm_config, bank_knee);
constexpr std::size_t kConfigSizeAbi8 = offsetof(tm_config, bank_pad_mean);
// (ABI 9's struct is 8-byte aligned: its size is where ABI 10's first field, a double, begins)
constexpr std::size_t kConfigSizeAbi9 = offsetof(tm_config, force_limit);
static_assert(kConfigSizeAbi2 < kConfigSizeAbi4 && kConfigSizeAbi4 < kConfigSizeAbi5 &&
              kConfigSizeAbi5 < kConfigSizeAbi6 && kConfigSizeAbi6 < kConfigSizeAbi7 &&
              kConfigSizeAbi7 < kConfigSizeAbi8 && kConfigSizeAbi8 < kConfigSizeAbi9 &&
              kConfigSizeAbi9 < sizeof(tm_config), "tm_config only grows");

static void config_defaults(tm_config* cfg) noexcept {
    std::memset(cfg, 0, sizeof *cfg);
    const PipelineConfig d;
    cfg->struct_size = sizeof(tm_config);
    cfg->abi_version = TM_ABI_VERSION;
    cfg->precision = 64;
    cfg->n_ridges = d.n_ridges;
    cfg->fs = d.fs;
    cfg->use_u = 1;
    cfg->v_limit = d.v_limit;
    cfg->u_limit = d.u_limit;
    cfg->weights_fs = 0.0;
    cfg->activation = 0;
    cfg->slip_threshold = d.slip_threshold;
    cfg->max_hold_ticks = d.max_hold_ticks;
    cfg->force_input = d.force_input;
    cfg->force_limit = d.force_limit;
    controller_to_c(tactile::default_controller(tactile::ControllerKind::none), &cfg->controller);
    const tactile::ControllerParams dc = tactile::default_controller(tactile::ControllerKind::none);
#define TM_TAIL_DEFAULT(name, def, laws, doc) cfg->name = dc.name;
    TM_CONTROLLER_TAIL_FIELDS(TM_TAIL_DEFAULT)
#undef TM_TAIL_DEFAULT
}

// The newest ABI whose tm_config fits in `size` bytes (sizes of the accepted range).
static uint32_t abi_for_size(std::size_t size) noexcept {
    if (size >= sizeof(tm_config)) return TM_ABI_VERSION;
    if (size >= kConfigSizeAbi9) return 9;
    if (size >= kConfigSizeAbi8) return 8;
    if (size >= kConfigSizeAbi7) return 7;
    if (size >= kConfigSizeAbi6) return 6;
    if (size >= kConfigSizeAbi5) return 5;
    if (size >= kConfigSizeAbi4) return 4;
    return 3;  // ABI 2 and 3 share their struct
}

int32_t tm_config_init_sized(tm_config* cfg, uint32_t size) {
    if (!cfg) return fail(TM_ERR_NULL, "cfg is NULL");
    if (size < kConfigSizeAbi2 || size > sizeof(tm_config))
        return fail(TM_ERR_VERSION, "size is %u, this library fills %u to %u bytes", unsigned(size),
                    unsigned(kConfigSizeAbi2), unsigned(sizeof(tm_config)));
    tm_config full;
    config_defaults(&full);
    full.struct_size = size;
    full.abi_version = abi_for_size(size);
    std::memcpy(cfg, &full, size);  // not one byte beyond the caller's struct
    return TM_OK;
}

// Programs built against the headers of ABI 6 and earlier call this symbol directly (the
// header's macro of the same name has replaced it since): an ABI-6 struct, never more.
int32_t (tm_config_init)(tm_config* cfg) {
    return tm_config_init_sized(cfg, static_cast<uint32_t>(kConfigSizeAbi6));
}

int32_t tm_pipeline_create(const tm_config* user_cfg, tm_pipeline* out) {
    if (!user_cfg) return fail(TM_ERR_NULL, "cfg is NULL");
    if (!out) return fail(TM_ERR_NULL, "out is NULL");
    *out = 0;
    const std::uint32_t size = user_cfg->struct_size;
    if (size < kConfigSizeAbi2 || size > sizeof(tm_config))
        return fail(TM_ERR_VERSION, "cfg->struct_size is %u, this library accepts %u to %u (call tm_config_init)",
                    unsigned(size), unsigned(kConfigSizeAbi2), unsigned(sizeof(tm_config)));
    if (user_cfg->abi_version < 2 || user_cfg->abi_version > TM_ABI_VERSION)
        return fail(TM_ERR_VERSION, "cfg->abi_version is %u, this library implements 2 to %d",
                    unsigned(user_cfg->abi_version), TM_ABI_VERSION);
    // A shorter (older) struct: the fields it lacks keep their defaults.
    tm_config full;
    config_defaults(&full);
    std::memcpy(&full, user_cfg, size);
    const tm_config* cfg = &full;
    if (cfg->precision != 64 && cfg->precision != 32)
        return fail(TM_ERR_ARGUMENT, "cfg->precision must be 64 or 32, got %d", int(cfg->precision));
    const int32_t dp = cfg->detector_precision == 0 ? cfg->precision : cfg->detector_precision;
    if (!(dp == cfg->precision || (cfg->precision == 64 && dp == 32)))
        return fail(TM_ERR_ARGUMENT, "cfg->detector_precision must be 0, the precision, or 32 with precision 64; got %d",
                    int(cfg->detector_precision));
    const int32_t kind = cfg->controller.kind;
    if (kind < 0 || kind > 2)
        return fail(TM_ERR_ARGUMENT, "controller.kind must be 0 (none), 1 (paper) or 2 (velocity), got %d", int(kind));
    PipelineConfig c;
    c.n_ridges = cfg->n_ridges;
    c.fs = cfg->fs;
    c.use_u = cfg->use_u != 0;
    c.sos_v = cfg->sos_v;
    c.n_sos_v = cfg->n_sos_v;
    c.sos_u = cfg->sos_u;
    c.n_sos_u = cfg->n_sos_u;
    c.sos_diff = cfg->sos_diff;
    c.n_sos_diff = cfg->n_sos_diff;
    c.v_limit = cfg->v_limit;
    c.u_limit = cfg->u_limit;
    c.n_hidden = cfg->n_hidden;
    c.w1 = cfg->w1;
    c.b1 = cfg->b1;
    c.w2 = cfg->w2;
    c.b2 = cfg->b2;
    c.input_mean = cfg->input_mean;
    c.input_gain = cfg->input_gain;
    c.weights_fs = cfg->weights_fs;
    c.activation = cfg->activation;
    c.slip_threshold = cfg->slip_threshold;
    c.max_hold_ticks = long(cfg->max_hold_ticks);
    c.controller = controller_from_c(cfg->controller);
#define TM_FROM_TAIL(name, def, laws, doc) c.controller.name = cfg->name;
    TM_CONTROLLER_TAIL_FIELDS(TM_FROM_TAIL)
#undef TM_FROM_TAIL
    c.shear_weights = cfg->shear_weights;
    c.detector_kind = cfg->detector_kind;
    c.bank_n_lp = cfg->bank_n_lp;
    c.bank_lp_taus = cfg->bank_lp_taus;
    c.bank_n_abs = cfg->bank_n_abs;
    c.bank_abs_taus = cfg->bank_abs_taus;
    c.bank_load_tau = cfg->bank_load_tau;
    c.bank_peak_tau = cfg->bank_peak_tau;
    c.bank_knee = cfg->bank_knee;  // NULL (its default) in a struct of ABI 7 or earlier
    c.bank_pad_mean = cfg->bank_pad_mean;  // 0 (its default) in a struct of ABI 8 or earlier
    c.force_input = cfg->force_input;      // 0 and 100 N (the defaults) in a struct of ABI 9 or earlier
    c.force_limit = cfg->force_limit;
    // The sample-rate check first, with its own code.
    if (std::isfinite(c.fs) && c.fs > 0 && std::isfinite(c.weights_fs) && c.weights_fs > 0 &&
        std::fabs(c.fs - c.weights_fs) > 1e-9 * c.fs)
        return fail(TM_ERR_FS, "weights_fs = %g Hz does not match fs = %g Hz: the detector was trained for another "
                    "sample rate", c.weights_fs, c.fs);
    std::unique_ptr<Instance> inst;
    try {
        inst = std::make_unique<Instance>();
        if (cfg->precision == 64 && dp == 32)
            inst->m = std::make_unique<MirrorPipeline<double, float>>(c);
        else if (cfg->precision == 64)
            inst->d = std::make_unique<MirrorPipeline<double>>(c);
        else
            inst->f = std::make_unique<MirrorPipeline<float>>(c);
    } catch (const std::invalid_argument& e) {
        return fail(TM_ERR_ARGUMENT, "%s", e.what());
    } catch (const std::bad_alloc&) {
        return fail(TM_ERR_MEMORY, "out of memory");
    } catch (const std::exception& e) {
        return fail(TM_ERR_INTERNAL, "%s", e.what());
    } catch (...) {
        return fail(TM_ERR_INTERNAL, "unknown exception while creating the pipeline");
    }
    std::lock_guard<std::mutex> lock(g_table_lock);
    for (std::uint32_t i = 0; i < kSlots; ++i) {
        Slot& s = g_slots[i];
        if (s.inst.load(std::memory_order_relaxed) == nullptr) {
            s.inst.store(inst.release(), std::memory_order_release);
            *out = (std::uint64_t(s.gen.load(std::memory_order_relaxed)) << 32) | std::uint64_t(i + 1);
            g_error[0] = '\0';
            return TM_OK;
        }
    }
    return fail(TM_ERR_MEMORY, "too many live pipelines (%u)", unsigned(kSlots));
}

int32_t tm_pipeline_destroy(tm_pipeline h) {
    // The table lock is held until the pipeline is freed, so the slot is not reused
    // while calls that entered before the generation changed are still running.
    std::lock_guard<std::mutex> lock(g_table_lock);
    const std::uint64_t idx = (h & 0xffffffffu);
    const std::uint32_t gen = std::uint32_t(h >> 32);
    if (idx == 0 || idx > kSlots)
        return fail(TM_ERR_HANDLE, "handle %llu is not a live pipeline", (unsigned long long)h);
    Slot& s = g_slots[idx - 1];
    if (s.gen.load(std::memory_order_seq_cst) != gen || !s.inst.load(std::memory_order_acquire))
        return fail(TM_ERR_HANDLE, "handle %llu is not a live pipeline", (unsigned long long)h);
    std::uint32_t next = gen + 1;
    if (next == 0) next = 1;  // generation 0 is never issued
    s.gen.store(next, std::memory_order_seq_cst);  // dead from here on: new calls fail
    Instance* victim = s.inst.exchange(nullptr, std::memory_order_acq_rel);
    // Calls in flight entered before the generation changed; wait for them. The
    // owner word moves to the new generation once it is free, so a stale handle can
    // never claim it again.
    for (;;) {
        std::uint64_t free_word = std::uint64_t(gen) << 1;
        if (s.owner.compare_exchange_weak(free_word, std::uint64_t(next) << 1, std::memory_order_seq_cst,
                                          std::memory_order_relaxed))
            break;
        std::this_thread::yield();
    }
    while (s.readers.load(std::memory_order_seq_cst) != 0) std::this_thread::yield();
    delete victim;
    return TM_OK;
}

int32_t tm_pipeline_sizes(tm_pipeline h, size_t* n_inputs, size_t* n_outputs) {
    TM_GET(h, in);
    if (!n_inputs || !n_outputs) return fail(TM_ERR_NULL, "n_inputs and n_outputs must not be NULL");
    with(in, [&](auto& p) {
        *n_inputs = p.n_inputs();
        *n_outputs = p.n_outputs();
        return 0;
    });
    return TM_OK;
}

int32_t tm_pipeline_step(tm_pipeline h, const double* x, size_t n_x, double* out, size_t n_out) {
    TM_DRIVE(h, in);
    if (!x) return fail(TM_ERR_NULL, "x is NULL");
    return with(in, [&](auto& p) -> int32_t {
        if (n_x != p.n_inputs())
            return fail(TM_ERR_SIZE, "n_x is %zu, the pipeline takes %zu inputs per tick", n_x, p.n_inputs());
        if (out && n_out != p.n_outputs())
            return fail(TM_ERR_SIZE, "n_out is %zu, the pipeline gives %zu outputs per tick", n_out, p.n_outputs());
        return p.step(x, out) ? TM_OK : TM_REJECTED;
    });
}

int32_t tm_pipeline_process_block(tm_pipeline h, const double* x, size_t n_ticks, size_t n_x, double* out,
                                  size_t n_out, uint8_t* accepted, size_t* n_rejected) {
    TM_DRIVE(h, in);
    if (n_ticks && !x) return fail(TM_ERR_NULL, "x is NULL");
    return with(in, [&](auto& p) -> int32_t {
        if (n_x != p.n_inputs())
            return fail(TM_ERR_SIZE, "n_x is %zu, the pipeline takes %zu inputs per tick", n_x, p.n_inputs());
        if (out && n_out != p.n_outputs())
            return fail(TM_ERR_SIZE, "n_out is %zu, the pipeline gives %zu outputs per tick", n_out, p.n_outputs());
        const std::size_t bad = p.process_block(x, n_ticks, n_x, out, n_out, nullptr, 0, accepted);
        if (n_rejected) *n_rejected = bad;
        return TM_OK;
    });
}

int32_t tm_pipeline_features(tm_pipeline h, double* f, size_t n_f) {
    TM_DRIVE(h, in);
    if (!f) return fail(TM_ERR_NULL, "f is NULL");
    return with(in, [&](auto& p) -> int32_t {
        if (n_f != p.n_features())
            return fail(TM_ERR_SIZE, "n_f is %zu, the pipeline has %zu features", n_f, p.n_features());
        p.last_features(f);
        return TM_OK;
    });
}

int32_t tm_pipeline_reset(tm_pipeline h, double x0) {
    TM_DRIVE(h, in);
    if (!std::isfinite(x0)) return fail(TM_ERR_ARGUMENT, "x0 must be finite");
    with(in, [&](auto& p) {
        p.reset(x0);
        return 0;
    });
    return TM_OK;
}

int32_t tm_pipeline_set_position(tm_pipeline h, double x) {
    TM_DRIVE(h, in);
    if (!std::isfinite(x)) return fail(TM_ERR_ARGUMENT, "x must be finite");
    with(in, [&](auto& p) {
        p.set_position(x);
        return 0;
    });
    return TM_OK;
}

int32_t tm_pipeline_get_status(tm_pipeline h, tm_pipeline_status* status) {
    TM_GET(h, in);
    if (!status) return fail(TM_ERR_NULL, "status is NULL");
    const std::uint32_t size = status->struct_size;
    if (size < sizeof(std::uint32_t) || size > sizeof(tm_pipeline_status))
        return fail(TM_ERR_VERSION, "status->struct_size is %u, expected %u (set it to sizeof(tm_pipeline_status))",
                    unsigned(size), unsigned(sizeof(tm_pipeline_status)));
    tm_pipeline_status s;
    std::memset(&s, 0, sizeof s);
    with(in, [&](auto& p) {
        const tactile::PipelineStatus st = p.published_status(&s.position, &s.velocity);
        s.ticks = st.ticks;
        s.rejected = st.rejected;
        s.nonfinite = st.nonfinite;
        s.out_of_range = st.out_of_range;
        s.overflow = st.overflow;
        s.last_bad_tick = st.last_bad_tick;
        s.last_bad_channel = st.last_bad_channel;
        s.consecutive_rejected = st.consecutive_rejected;
        s.fault = st.fault;
        s.slip = st.slip;
        s.at_limit = st.at_limit;
        s.last_reason = st.last_reason;
        return 0;
    });
    s.struct_size = size;
    std::memcpy(status, &s, size);
    return TM_OK;
}

int32_t tm_pipeline_time_step_ns(tm_pipeline h, int64_t n_iter, double* ns) {
    TM_DRIVE(h, in);
    if (!ns) return fail(TM_ERR_NULL, "ns is NULL");
    if (n_iter < 1) return fail(TM_ERR_ARGUMENT, "n_iter must be >= 1");
    try {
        *ns = with(in, [&](auto& p) { return p.time_step_ns(long(n_iter), 5); });
    } catch (const std::bad_alloc&) {
        return fail(TM_ERR_MEMORY, "out of memory");
    } catch (...) {
        return fail(TM_ERR_INTERNAL, "timing failed");
    }
    return TM_OK;
}

}  // extern "C"
