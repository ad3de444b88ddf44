// The tactile-mirror real-time path: sensor samples in, stage command out.
//
// MirrorPipeline<T> runs, once per tick (one sample per channel):
//
//   samples  -> check    every sample finite and within its limit, or the tick is
//                        rejected as a whole (counted; all state kept)
//            -> rate     stress rate of every strip:  SosCascade on v_out
//                        (or the raw v_out when no equaliser is configured)
//            -> rate2    2nd-order stress rate:       SosCascade on u_out, or the
//                        digital differentiator SosCascade on rate
//            -> detector Jordan MLP, one instance per ridge, features
//                        [rate_L, rate_R, rate2_L, rate2_R]
//            -> controller  stage command (position, velocity) from the largest
//                        y_pred of the ridges in use, direction from the L/R asymmetry
//
// Channel layout of a tick (double precision in and out, whatever T is):
//
//   x   = [v_L0, v_R0, v_L1, v_R1, ..., (u_L0, u_R0, ... when u_out is sampled)]
//   out = [x_cmd (m), v_cmd (m/s), y_slip_0, y_non_0, y_pred_0, y_slip_1, ...]
//
// Real-time contract (RTNeural / iir1 style): every size is fixed at construction,
// the only place that allocates or throws (std::invalid_argument naming the field).
// step(), process_block(), reset() and the status readers allocate nothing, throw
// nothing and never abort. Parts that a configuration does not use are not built
// and cost nothing: no equaliser (raw features), no u_out (differentiator instead),
// no controller, ridges not in use (they are simply not channels).
//
// Controllers (y = max over ridges of y_pred, dt = 1/fs, dir in {-1, 0, +1}):
//
//   direction  a <- exp(-dt/asym_tau) a + dt * sum_r (rate_L,r - rate_R,r): a leaky
//              integral of the stress-rate asymmetry, i.e. the L/R stress difference
//              (shear load) high-passed at 1/(2 pi asym_tau). dir = direction_sign *
//              sign(a) while |a| > asym_deadband, else the previous dir (0 at start).
//   paper      (the paper's law, section 4.2.2) every tick with y >= threshold the
//              stage target moves by dir * gain * y * dt (gain in m/s per unit
//              y_pred): a displacement proportional to y_pred above its threshold.
//              Only the travel limits [x_min, x_max] are enforced.
//   velocity   a velocity command with a deadband and a linear ramp on y_pred, plus
//              an optional shear feedback on the asymmetry a (which is proportional to
//              the L/R stress difference, i.e. to the shear load the finger puts on the pad):
//              v_des = dir * ramp_gain * v_max * s
//                      + direction_sign * shear_gain * (1 + pred_boost * s) * a,   clipped to +-v_max,
//              with s = clip((y - threshold) / (y_full - threshold), 0, 1). The ramp term
//              is a relay on sign(a): with the stage's lag it can limit-cycle, so a
//              law can instead (ramp_gain = 0) let y_pred only raise the gain of the
//              proportional shear loop as the contact nears slip (pred_boost),
//              limited so that the stage can always stop before a travel limit
//              (v^2 / (2 a_max) + |v| dt / 2 <= d, the distance left), then slewed
//              at most a_max * dt per tick and integrated into the position target.
//              Speed, acceleration and travel are all respected.
//
// Slip guard (both laws, slip_hold > 0): while the detector reports gross slip and for
// slip_hold seconds after, the controller holds as in a fault; then the asymmetry is
// tared again (the re-stuck contact is the new reference).
//
// Arming (both laws): for the first arm_delay seconds after a reset the command holds
// (the finger settles on the pad); at the end the asymmetry integrator is zeroed, so the
// shear of the settled contact is the reference (a tare).
//
// After more than max_hold_ticks consecutive rejected ticks the pipeline enters a
// fault state: the controller sees y = 0 and no shear (the stage stops: at once for
// the paper law, decelerating at a_max for the velocity law) until an accepted tick
// arrives.
// While fewer ticks are rejected the controller keeps running on the last accepted
// detector outputs, so an isolated dropped sample does not jerk the stage.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "jordan_mlp.hpp"
#include "sos.hpp"

namespace tactile {

enum class ControllerKind : int { none = 0, paper = 1, velocity = 2 };

inline const char* controller_name(ControllerKind k) noexcept {
    switch (k) {
        case ControllerKind::paper: return "paper";
        case ControllerKind::velocity: return "velocity";
        default: return "none";
    }
}

struct ControllerParams {
    ControllerKind kind = ControllerKind::none;
    double threshold = 0.5;        // y_pred threshold (paper) / start of the ramp (velocity)
    double gain = 0.01;            // paper: m/s of target motion per unit y_pred
    double y_full = 0.9;           // velocity: y_pred at which the speed is v_max
    double v_max = 0.05;           // velocity: m/s
    double a_max = 2.0;            // velocity: m/s^2
    double x_min = -0.05;          // travel limits, m
    double x_max = 0.05;
    double direction_sign = 1.0;   // +1 or -1: stage direction for a positive L-R asymmetry
    double asym_tau = 1.0;         // s, time constant of the asymmetry integrator
    double asym_deadband = 0.0;    // units of rate * s (Pa for stress-rate features)
    double shear_gain = 0.0;       // velocity: m/s per unit of asymmetry (shear feedback), >= 0
    double arm_delay = 0.0;        // s after reset during which the stage holds; then the asymmetry is tared
    double ramp_gain = 1.0;        // velocity: share of v_max the y_pred ramp commands (0: no ramp term), >= 0
    double pred_boost = 0.0;       // velocity: shear gain x (1 + pred_boost * ramp(y)), >= 0
    double slip_hold = 0.0;        // s, >= 0: on detected slip, hold and re-tare after this long (0: off)
};

// Everything a pipeline is built from. Arrays are borrowed for the duration of the
// constructor only (they are copied).
struct PipelineConfig {
    int n_ridges = 6;
    double fs = 1000.0;            // Hz
    bool use_u = true;             // u_out is sampled (else: digital differentiator)
    const double* sos_v = nullptr; // (n_sos_v, 6) equaliser v_out -> rate; none: raw v_out
    int n_sos_v = 0;
    const double* sos_u = nullptr; // (n_sos_u, 6) equaliser u_out -> rate2; none: raw u_out
    int n_sos_u = 0;
    const double* sos_diff = nullptr;  // (n_sos_diff, 6) differentiator rate -> rate2 (use_u = false)
    int n_sos_diff = 0;
    double v_limit = std::numeric_limits<double>::max();  // |v_out| above this: rejected
    double u_limit = std::numeric_limits<double>::max();
    // detector
    int n_hidden = 0;
    const double* w1 = nullptr;    // (n_hidden, 5)
    const double* b1 = nullptr;    // (n_hidden)
    const double* w2 = nullptr;    // (2, n_hidden)
    const double* b2 = nullptr;    // (2)
    const double* input_mean = nullptr;  // (4)
    const double* input_gain = nullptr;  // (4)
    double weights_fs = 0.0;       // Hz the weights were trained for; must equal fs
    int activation = 0;            // 0 exact, 1 fast
    double slip_threshold = 0.8;
    long max_hold_ticks = 100;
    ControllerParams controller;
};

struct PipelineStatus {
    std::uint64_t ticks = 0;          // step() calls (accepted + rejected)
    std::uint64_t rejected = 0;       // rejected ticks
    std::uint64_t nonfinite = 0;      // rejected ticks with a NaN/Inf sample
    std::uint64_t out_of_range = 0;   // rejected ticks with a finite sample beyond its limit
    std::int64_t last_bad_tick = -1;  // tick index of the last rejected tick
    int last_bad_channel = -1;        // first bad channel of that tick
    std::uint32_t consecutive_rejected = 0;
    bool fault = false;               // more than max_hold_ticks consecutive rejections
    bool slip = false;                // max y_slip >= slip_threshold at the last accepted tick
    bool at_limit = false;            // the command sits on a travel limit
};

// ---- validation shared by every binding -------------------------------------------

inline void check_finite_array(const double* a, std::size_t n, const char* name) {
    for (std::size_t i = 0; i < n; ++i)
        if (!std::isfinite(a[i])) throw std::invalid_argument(std::string(name) + " must be finite");
}

inline void validate_controller(const ControllerParams& c) {
    auto bad = [](const char* name, const std::string& why) {
        throw std::invalid_argument(std::string("controller.") + name + " " + why);
    };
    const int k = static_cast<int>(c.kind);
    if (k < 0 || k > 2) bad("kind", "must be 0 (none), 1 (paper) or 2 (velocity)");
    const double vals[] = {c.threshold, c.gain, c.y_full, c.v_max, c.a_max, c.x_min, c.x_max,
                           c.direction_sign, c.asym_tau, c.asym_deadband, c.shear_gain, c.arm_delay,
                           c.ramp_gain, c.pred_boost, c.slip_hold};
    const char* names[] = {"threshold", "gain", "y_full", "v_max", "a_max", "x_min", "x_max",
                           "direction_sign", "asym_tau", "asym_deadband", "shear_gain", "arm_delay",
                           "ramp_gain", "pred_boost", "slip_hold"};
    for (int i = 0; i < 15; ++i)
        if (!std::isfinite(vals[i])) bad(names[i], "must be finite");
    if (!(c.threshold >= 0.0 && c.threshold < 1.0)) bad("threshold", "must lie in [0, 1)");
    if (!(c.gain >= 0.0)) bad("gain", "must be >= 0 (m/s per unit y_pred)");
    if (c.kind == ControllerKind::velocity && !(c.y_full > c.threshold && c.y_full <= 1.0))
        bad("y_full", "must lie in (threshold, 1]");
    if (!(c.v_max > 0.0)) bad("v_max", "must be > 0 (m/s)");
    if (!(c.a_max > 0.0)) bad("a_max", "must be > 0 (m/s^2)");
    if (!(c.x_min < c.x_max)) bad("x_max", "must be greater than x_min");
    if (!(c.x_min <= 0.0 && c.x_max >= 0.0)) bad("x_min", "and x_max must bracket 0 (the start position)");
    if (!(c.direction_sign == 1.0 || c.direction_sign == -1.0)) bad("direction_sign", "must be +1 or -1");
    if (!(c.asym_tau > 0.0)) bad("asym_tau", "must be > 0 (s)");
    if (!(c.asym_deadband >= 0.0)) bad("asym_deadband", "must be >= 0");
    if (!(c.shear_gain >= 0.0)) bad("shear_gain", "must be >= 0 (m/s per unit of asymmetry)");
    if (!(c.arm_delay >= 0.0 && c.arm_delay <= 3600.0)) bad("arm_delay", "must lie in [0, 3600] s");
    if (!(c.ramp_gain >= 0.0)) bad("ramp_gain", "must be >= 0 (share of v_max)");
    if (!(c.pred_boost >= 0.0)) bad("pred_boost", "must be >= 0");
    if (!(c.slip_hold >= 0.0 && c.slip_hold <= 3600.0)) bad("slip_hold", "must lie in [0, 3600] s");
}

inline void validate_config(const PipelineConfig& c) {
    auto bad = [](const std::string& m) { throw std::invalid_argument(m); };
    if (c.n_ridges < 1 || c.n_ridges > 64) bad("n_ridges must lie in [1, 64], got " + std::to_string(c.n_ridges));
    if (!std::isfinite(c.fs) || !(c.fs > 0.0)) bad("fs must be a positive finite number of Hz");
    if (!std::isfinite(c.weights_fs) || !(c.weights_fs > 0.0))
        bad("weights_fs must be the positive sample rate (Hz) the detector was trained for");
    if (std::fabs(c.fs - c.weights_fs) > 1e-9 * c.fs)
        bad("weights_fs = " + std::to_string(c.weights_fs) + " Hz does not match fs = " + std::to_string(c.fs) +
            " Hz: the detector was trained for another sample rate");
    auto sos_ok = [&](const double* s, int n, const char* name) {
        if (n < 0 || n > 64) bad(std::string(name) + ": the number of sections must lie in [0, 64]");
        if (n > 0 && !s) bad(std::string(name) + " is a null pointer");
        if (n > 0) check_finite_array(s, std::size_t(n) * 6, name);
    };
    sos_ok(c.sos_v, c.n_sos_v, "sos_v");
    if (c.use_u) {
        sos_ok(c.sos_u, c.n_sos_u, "sos_u");
        if (c.n_sos_diff != 0) bad("sos_diff must be empty when u_out is sampled (use_u)");
    } else {
        if (c.n_sos_u != 0) bad("sos_u must be empty without u_out (use_u false)");
        sos_ok(c.sos_diff, c.n_sos_diff, "sos_diff");
        if (c.n_sos_diff < 1) bad("sos_diff must have at least one section without u_out (use_u false)");
    }
    if (std::isnan(c.v_limit) || !(c.v_limit > 0.0)) bad("v_limit must be > 0");
    if (std::isnan(c.u_limit) || !(c.u_limit > 0.0)) bad("u_limit must be > 0");
    if (c.n_hidden < 1 || c.n_hidden > 1024) bad("n_hidden must lie in [1, 1024]");
    const std::size_t h = std::size_t(c.n_hidden);
    const double* arrs[] = {c.w1, c.b1, c.w2, c.b2, c.input_mean, c.input_gain};
    const char* names[] = {"w1", "b1", "w2", "b2", "input_mean", "input_gain"};
    const std::size_t sizes[] = {h * 5, h, 2 * h, 2, 4, 4};
    for (int i = 0; i < 6; ++i) {
        if (!arrs[i]) bad(std::string(names[i]) + " is a null pointer");
        check_finite_array(arrs[i], sizes[i], names[i]);
    }
    if (c.activation != 0 && c.activation != 1) bad("activation must be 0 (exact) or 1 (fast)");
    if (!(c.slip_threshold > 0.0 && c.slip_threshold < 1.0)) bad("slip_threshold must lie in (0, 1)");
    if (c.max_hold_ticks < 0) bad("max_hold_ticks must be >= 0");
    validate_controller(c.controller);
}

// ---- controllers --------------------------------------------------------------------

// Stage command from the detector. Double precision whatever the pipeline's T.
class StageController {
public:
    StageController() = default;
    StageController(const ControllerParams& p, double fs) : p_(p), dt_(1.0 / fs) {
        validate_controller(p);
        leak_ = std::exp(-dt_ / p.asym_tau);
        arm_ticks_ = static_cast<std::uint64_t>(std::llround(p.arm_delay * fs));
        hold_ticks_ = static_cast<std::uint64_t>(std::llround(p.slip_hold * fs));
    }

    // y: max y_pred of the ridges; asym: sum over ridges of (rate_L - rate_R);
    // fault: no valid input any more, bring the stage to rest; slip: the detector
    // reports gross slip now (any ridge's y_slip at its threshold).
    TM_ALWAYS_INLINE void step(double y, double asym, bool fault = false, bool slip = false) noexcept {
        if (ticks_ < arm_ticks_) {  // arming: hold, then tare the asymmetry
            if (++ticks_ == arm_ticks_) {
                a_ = 0.0;
                dir_ = 0.0;
            }
            v_ = 0.0;
            return;
        }
        // Slip guard: while the contact slides, the strips' asymmetry no longer measures
        // the relative displacement (sliding friction holds it, and the release of
        // static friction swings it), so acting on it can run the stage away. Hold
        // (as in a fault) until slip_hold after the last detected slip, then tare:
        // the re-stuck contact is the new reference.
        if (hold_ticks_ > 0) {
            if (slip) hold_left_ = hold_ticks_;
            if (hold_left_ > 0) {
                fault = true;
                y = 0.0;
                asym = 0.0;
                if (--hold_left_ == 0) {
                    a_ = 0.0;
                    dir_ = 0.0;
                }
            }
        }
        a_ = leak_ * a_ + dt_ * asym;
        if (std::fabs(a_) > p_.asym_deadband) dir_ = (a_ > 0.0 ? p_.direction_sign : -p_.direction_sign);
        switch (p_.kind) {
            case ControllerKind::paper: {
                const double x0 = x_;
                if (y >= p_.threshold) x_ = clamp(x_ + dir_ * p_.gain * y * dt_);
                v_ = (x_ - x0) / dt_;
                break;
            }
            case ControllerKind::velocity: {
                double s = (y - p_.threshold) / (p_.y_full - p_.threshold);
                s = s < 0.0 ? 0.0 : (s > 1.0 ? 1.0 : s);
                const double g = p_.shear_gain * (1.0 + p_.pred_boost * s);
                double vd = dir_ * p_.ramp_gain * p_.v_max * s + (fault ? 0.0 : p_.direction_sign * g * a_);
                vd = vd > p_.v_max ? p_.v_max : (vd < -p_.v_max ? -p_.v_max : vd);
                // Largest speed from which decelerating by a_max dt per tick stops
                // within the distance d left: v^2 / (2 a) + v dt / 2 <= d, i.e.
                // (v + h)^2 <= h^2 + 2 a d with h = a dt / 2. The square root is only
                // taken when the bound is hit.
                const double h = 0.5 * p_.a_max * dt_;
                if (vd > 0.0) {
                    const double d = std::max(0.0, p_.x_max - x_);
                    if (vd * (vd + 2.0 * h) > 2.0 * p_.a_max * d) vd = std::sqrt(h * h + 2.0 * p_.a_max * d) - h;
                } else if (vd < 0.0) {
                    const double d = std::max(0.0, x_ - p_.x_min);
                    if (vd * (vd - 2.0 * h) > 2.0 * p_.a_max * d) vd = h - std::sqrt(h * h + 2.0 * p_.a_max * d);
                }
                const double dv_max = p_.a_max * dt_;
                double dv = vd - v_;
                dv = dv > dv_max ? dv_max : (dv < -dv_max ? -dv_max : dv);
                v_ += dv;
                const double x0 = x_, xn = x_ + v_ * dt_;
                x_ = clamp(xn);
                if (x_ != xn) v_ = (x_ - x0) / dt_;  // the speed actually left at the limit
                break;
            }
            default: break;
        }
    }
    void reset(double x0 = 0.0) noexcept {
        x_ = clamp(x0);
        v_ = 0.0;
        a_ = 0.0;
        dir_ = 0.0;
        ticks_ = 0;
        hold_left_ = 0;
    }
    void set_position(double x) noexcept {
        x_ = clamp(x);
        v_ = 0.0;
    }
    double position() const noexcept { return x_; }
    double velocity() const noexcept { return v_; }
    double asymmetry() const noexcept { return a_; }
    double direction() const noexcept { return dir_; }
    bool at_limit() const noexcept { return x_ <= p_.x_min || x_ >= p_.x_max; }
    const ControllerParams& params() const noexcept { return p_; }

private:
    double clamp(double x) const noexcept { return x < p_.x_min ? p_.x_min : (x > p_.x_max ? p_.x_max : x); }
    ControllerParams p_{};
    double dt_ = 1e-3, leak_ = 1.0;
    double x_ = 0.0, v_ = 0.0, a_ = 0.0, dir_ = 0.0;
    std::uint64_t ticks_ = 0, arm_ticks_ = 0, hold_ticks_ = 0, hold_left_ = 0;
};

// ---- the pipeline -------------------------------------------------------------------

// T: arithmetic of the filters; TD: arithmetic of the detector (default T). The
// mixed MirrorPipeline<double, float> keeps double filters (slow poles at kHz rates)
// and runs the detector, the dominant cost, in float.
template <typename T, typename TD = T>
class MirrorPipeline {
    static_assert(std::is_same<T, float>::value || std::is_same<T, double>::value,
                  "MirrorPipeline supports float and double");
    static_assert(std::is_same<TD, float>::value || std::is_same<TD, double>::value,
                  "MirrorPipeline's detector supports float and double");
    using Mlp = detector::JordanMLP<TD>;

public:
    static constexpr int kFeatures = 4;  // rate_L, rate_R, rate2_L, rate2_R

    explicit MirrorPipeline(const PipelineConfig& c) {
        validate_config(c);
        R_ = c.n_ridges;
        nch_ = std::size_t(2 * R_);
        fs_ = c.fs;
        use_u_ = c.use_u;
        v_limit_ = c.v_limit;
        u_limit_ = c.u_limit;
        slip_threshold_ = c.slip_threshold;
        max_hold_ = c.max_hold_ticks;
        // Cascades run in the structure sosfilt would pick for T ("auto": delta
        // sections for float's low-frequency poles, tdf2 otherwise).
        if (c.n_sos_v > 0) rate_f_ = make_cascade(c.sos_v, c.n_sos_v);
        if (use_u_ && c.n_sos_u > 0) rate2_f_ = make_cascade(c.sos_u, c.n_sos_u);
        if (!use_u_) rate2_f_ = make_cascade(c.sos_diff, c.n_sos_diff);
        mlp_ = std::make_unique<Mlp>(kFeatures, c.n_hidden, R_, c.w1, c.b1, c.w2, c.b2, c.input_mean,
                                     c.input_gain,
                                     c.activation == 1 ? detector::Activation::fast
                                                       : detector::Activation::exact);
        ctrl_ = StageController(c.controller, c.fs);
        ctrl_kind_ = c.controller.kind;
        xin_.resize(n_inputs());
        rate_.resize(nch_);
        rate2_.resize(nch_);
        feat_.resize(std::size_t(R_) * kFeatures);
        det_.resize(std::size_t(R_) * 3);
        out_.resize(n_outputs());
        std::fill(out_.begin(), out_.end(), 0.0);
        for (int r = 0; r < R_; ++r) out_[2 + 3 * r + 1] = 1.0;  // y_non of a silent pad
    }

    MirrorPipeline(const MirrorPipeline&) = delete;
    MirrorPipeline& operator=(const MirrorPipeline&) = delete;

    int n_ridges() const noexcept { return R_; }
    double fs() const noexcept { return fs_; }
    bool use_u() const noexcept { return use_u_; }
    std::size_t n_inputs() const noexcept { return nch_ * (use_u_ ? 2 : 1); }
    std::size_t n_outputs() const noexcept { return 2 + 3 * std::size_t(R_); }
    std::size_t n_features() const noexcept { return std::size_t(R_) * kFeatures; }
    bool has_rate_filter() const noexcept { return bool(rate_f_); }
    bool has_rate2_filter() const noexcept { return bool(rate2_f_); }
    ControllerKind controller_kind() const noexcept { return ctrl_kind_; }
    const StageController& controller() const noexcept { return ctrl_; }
    const PipelineStatus& status() const noexcept { return st_; }
    const double* last_output() const noexcept { return out_.data(); }
    const char* simd_path() const noexcept { return simd::isa_name(mlp_->isa()); }
    simd::Isa filter_isa() const noexcept { return simd::detect_isa(); }

    // Features of the last accepted tick: (n_ridges, 4) [rate_L, rate_R, rate2_L, rate2_R]
    // (in the detector's precision).
    void last_features(double* f) const noexcept {
        for (std::size_t i = 0; i < feat_.size(); ++i) f[i] = double(feat_[i]);
    }

    // One tick: x[n_inputs] -> out[n_outputs] (out may be null). Returns false when
    // the tick was rejected (out then holds the previous detector outputs and the
    // controller's command for this tick).
    bool step(const double* x, double* out) noexcept {
        DenormalGuard guard;
        const bool ok = tick(x);
        if (out)
            for (std::size_t i = 0; i < out_.size(); ++i) out[i] = out_[i];
        return ok;
    }

    // n ticks: x[t * x_stride + c], out[t * out_stride + k]; features (optional)
    // f[t * f_stride + r * 4 + i]; accepted (optional) 1/0 per tick. Identical to n
    // calls of step(). Returns the number of rejected ticks.
    std::size_t process_block(const double* x, std::size_t n, std::size_t x_stride, double* out,
                              std::size_t out_stride, double* f = nullptr, std::size_t f_stride = 0,
                              std::uint8_t* accepted = nullptr) noexcept {
        DenormalGuard guard;
        std::size_t bad = 0;
        const std::size_t no = out_.size(), nf = feat_.size();
        for (std::size_t t = 0; t < n; ++t) {
            const bool ok = tick(x + t * x_stride);
            bad += !ok;
            if (out)
                for (std::size_t i = 0; i < no; ++i) out[t * out_stride + i] = out_[i];
            if (f)
                for (std::size_t i = 0; i < nf; ++i) f[t * f_stride + i] = double(feat_[i]);
            if (accepted) accepted[t] = ok ? 1 : 0;
        }
        return bad;
    }

    // Back to rest: filters and detector state zero, controller at x0, counters cleared.
    void reset(double x0 = 0.0) noexcept {
        if (rate_f_) rate_f_->reset();
        if (rate2_f_) rate2_f_->reset();
        mlp_->reset();
        ctrl_.reset(x0);
        st_ = PipelineStatus{};
        for (std::size_t i = 0; i < feat_.size(); ++i) feat_[i] = TD(0);
        for (std::size_t i = 0; i < det_.size(); ++i) det_[i] = TD(0);
        std::fill(out_.begin(), out_.end(), 0.0);
        for (int r = 0; r < R_; ++r) {
            out_[2 + 3 * r + 1] = 1.0;
        }
        out_[0] = ctrl_.position();
    }

    // Tell the controller where the stage is (m), e.g. after homing; velocity zero.
    void set_position(double x) noexcept {
        ctrl_.set_position(x);
        out_[0] = ctrl_.position();
        out_[1] = 0.0;
    }

    // Mean time of one step() in ns, measured inside C++ over n_iter ticks on a
    // synthetic input (smooth signals a few percent of the limits), best of
    // `repeats`. All state is restored afterwards. Not real-time (allocates).
    double time_step_ns(long n_iter, int repeats = 5) {
        const std::size_t ni = n_inputs(), period = 1024;
        std::vector<double> x(period * ni), o(out_.size());
        for (std::size_t t = 0; t < period; ++t)
            for (std::size_t c = 0; c < ni; ++c)
                x[t * ni + c] = 1e-3 * std::sin(0.01 * double(t) * double(c + 1) + double(c));
        Snapshot snap = save();
        double best = std::numeric_limits<double>::infinity();
        DenormalGuard guard;
        for (int r = 0; r < repeats; ++r) {
            const auto t0 = std::chrono::steady_clock::now();
            for (long i = 0; i < n_iter; ++i) step(x.data() + (std::size_t(i) % period) * ni, o.data());
            const auto t1 = std::chrono::steady_clock::now();
            best = std::min(best, std::chrono::duration<double, std::nano>(t1 - t0).count() / double(n_iter));
        }
        restore(snap);
        return best;
    }

private:
    std::unique_ptr<SosCascade<T>> make_cascade(const double* sos, int n) {
        std::vector<SectionForm> forms(std::size_t(n), SectionForm::tdf2);
        if (std::is_same<T, float>::value)
            for (int s = 0; s < n; ++s)
                if (-(sos[6 * s + 4] / sos[6 * s + 3]) > 0.0) forms[std::size_t(s)] = SectionForm::delta;
        return std::make_unique<SosCascade<T>>(sos, std::size_t(n), nch_, forms.data());
    }

    // Sample check: |x| <= limit is false for NaN, and limits are finite, so one
    // comparison per sample catches NaN, +-Inf and out-of-range values.
    TM_ALWAYS_INLINE bool samples_ok(const double* x) const noexcept {
        bool ok = true;
        for (std::size_t c = 0; c < nch_; ++c) ok &= std::fabs(x[c]) <= v_limit_;
        if (use_u_)
            for (std::size_t c = 0; c < nch_; ++c) ok &= std::fabs(x[nch_ + c]) <= u_limit_;
        return ok;
    }

    void record_rejection(const double* x) noexcept {
        const std::size_t ni = n_inputs();
        bool nonfinite = false;
        int first = -1;
        for (std::size_t c = 0; c < ni; ++c) {
            const double lim = c < nch_ ? v_limit_ : u_limit_;
            const bool fin = is_finite(x[c]);
            if (!fin || std::fabs(x[c]) > lim) {
                if (first < 0) first = int(c);
                nonfinite |= !fin;
            }
        }
        ++st_.rejected;
        if (nonfinite)
            ++st_.nonfinite;
        else
            ++st_.out_of_range;
        st_.last_bad_tick = std::int64_t(st_.ticks);
        st_.last_bad_channel = first;
        ++st_.consecutive_rejected;
        if (st_.consecutive_rejected > std::uint64_t(max_hold_)) st_.fault = true;
    }

    TM_ALWAYS_INLINE bool tick(const double* x) noexcept {
        const bool ok = samples_ok(x);
        if (!ok) {
            record_rejection(x);
        } else {
            st_.consecutive_rejected = 0;
            st_.fault = false;
            estimate(x);
            mlp_->step(feat_.data(), det_.data());
        }
        // Detector outputs (held on a rejected tick) -> controller.
        double y = 0.0, ys = 0.0, asym = 0.0;
        for (int r = 0; r < R_; ++r) {
            const TD* d = det_.data() + 3 * r;
            ys = std::max(ys, double(d[0]));
            y = std::max(y, double(d[2]));
            if (ok) {
                out_[2 + 3 * r + 0] = double(d[0]);
                out_[2 + 3 * r + 1] = double(d[1]);
                out_[2 + 3 * r + 2] = double(d[2]);
            }
            asym += double(feat_[kFeatures * r + 0]) - double(feat_[kFeatures * r + 1]);
        }
        if (ok) st_.slip = ys >= slip_threshold_;
        if (!ok) asym = 0.0;  // no new rate information: the integrator only leaks
        if (st_.fault) y = 0.0;
        if (ctrl_kind_ != ControllerKind::none) ctrl_.step(y, asym, st_.fault, st_.slip);
        out_[0] = ctrl_.position();
        out_[1] = ctrl_.velocity();
        st_.at_limit = ctrl_kind_ != ControllerKind::none && ctrl_.at_limit();
        ++st_.ticks;
        return ok;
    }

    // Samples -> features (n_ridges, 4).
    TM_ALWAYS_INLINE void estimate(const double* x) noexcept {
        const T* xv;
        const T* xu;
        if constexpr (std::is_same<T, double>::value) {
            xv = x;
            xu = x + nch_;
        } else {
            const std::size_t ni = n_inputs();
            for (std::size_t c = 0; c < ni; ++c) xin_[c] = T(x[c]);
            xv = xin_.data();
            xu = xin_.data() + nch_;
        }
        const T* rate = xv;
        if (rate_f_) {
            rate_f_->step(xv, rate_.data());
            rate = rate_.data();
        }
        const T* rate2;
        if (use_u_) {
            rate2 = xu;
            if (rate2_f_) {
                rate2_f_->step(xu, rate2_.data());
                rate2 = rate2_.data();
            }
        } else {
            rate2_f_->step(rate, rate2_.data());
            rate2 = rate2_.data();
        }
        TD* f = feat_.data();
        for (int r = 0; r < R_; ++r) {
            f[kFeatures * r + 0] = TD(rate[2 * r]);
            f[kFeatures * r + 1] = TD(rate[2 * r + 1]);
            f[kFeatures * r + 2] = TD(rate2[2 * r]);
            f[kFeatures * r + 3] = TD(rate2[2 * r + 1]);
        }
    }

    struct Snapshot {
        std::vector<T> z1, z2;
        std::vector<TD> mlp, feat, det;
        std::vector<double> out;
        StageController ctrl;
        PipelineStatus st;
    };
    Snapshot save() const {
        Snapshot s;
        if (rate_f_) {
            s.z1.resize(rate_f_->sections() * nch_ * 2);
            rate_f_->get_state(s.z1.data());
        }
        if (rate2_f_) {
            s.z2.resize(rate2_f_->sections() * nch_ * 2);
            rate2_f_->get_state(s.z2.data());
        }
        s.mlp.resize(std::size_t(R_));
        mlp_->get_state(s.mlp.data());
        s.feat.assign(feat_.data(), feat_.data() + feat_.size());
        s.det.assign(det_.data(), det_.data() + det_.size());
        s.out = out_;
        s.ctrl = ctrl_;
        s.st = st_;
        return s;
    }
    void restore(const Snapshot& s) noexcept {
        if (rate_f_) rate_f_->set_state(s.z1.data());
        if (rate2_f_) rate2_f_->set_state(s.z2.data());
        mlp_->set_state(s.mlp.data());
        std::copy(s.feat.begin(), s.feat.end(), feat_.data());
        std::copy(s.det.begin(), s.det.end(), det_.data());
        out_ = s.out;
        ctrl_ = s.ctrl;
        st_ = s.st;
    }

    int R_ = 0;
    std::size_t nch_ = 0;
    double fs_ = 0.0;
    bool use_u_ = true;
    double v_limit_ = 0.0, u_limit_ = 0.0, slip_threshold_ = 0.8;
    long max_hold_ = 0;
    std::unique_ptr<SosCascade<T>> rate_f_, rate2_f_;
    std::unique_ptr<Mlp> mlp_;
    StageController ctrl_;
    ControllerKind ctrl_kind_ = ControllerKind::none;
    AlignedBuffer<T> xin_, rate_, rate2_;
    AlignedBuffer<TD> feat_, det_;
    std::vector<double> out_;
    PipelineStatus st_;
};

}  // namespace tactile
