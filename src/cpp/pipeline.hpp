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
//                        [rate_L, rate_R, rate2_L, rate2_R] (detector_kind 0, the
//                        paper's net) or those plus a bank of first-order filters
//                        over them (detector_kind 1, detector_bank.hpp)
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
// nothing, take no lock and never abort. One thread steps a pipeline at a time (the
// bindings enforce it with an atomic owner flag, owner.hpp); published_status() may
// be read from any thread. Parts that a configuration does not use are not built
// and cost nothing: no equaliser (raw features), no u_out (differentiator instead),
// no controller, ridges not in use (they are simply not channels).
//
// The controllers (the direction, paper and velocity laws, the slip guard, the
// command and arming) are described in controller.hpp; the configuration and its
// checks are in pipeline_config.hpp, the status and its publication in
// pipeline_status.hpp.
//
// After more than max_hold_ticks consecutive rejected ticks the pipeline enters a
// fault state: the controller sees y = 0 and no shear (the stage stops: at once for
// the paper law, decelerating at a_max for the velocity law) until an accepted tick
// arrives.
// While fewer ticks are rejected the controller keeps running on the last accepted
// detector outputs, so an isolated dropped sample does not jerk the stage.
#pragma once

#include <algorithm>
#include <atomic>
#include <cstring>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <vector>

#include "controller.hpp"
#include "detector_bank.hpp"
#include "jordan_mlp.hpp"
#include "pipeline_config.hpp"
#include "pipeline_status.hpp"
#include "sos.hpp"

namespace tactile {

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
    using Bank = detector::BankJordan<TD>;

public:
    static constexpr int kFeatures = 4;  // rate_L, rate_R, rate2_L, rate2_R

    explicit MirrorPipeline(const PipelineConfig& c) {
        validate_config(c);
        R_ = c.n_ridges;
        nch_ = std::size_t(2 * R_);
        fs_ = c.fs;
        use_u_ = c.use_u;
        // A float32 pipeline refuses samples its filters cannot hold as out of range:
        // beyond FLT_MAX the cast gives inf, the cascade drops the sample while the
        // rest of the tick advances, and the paths fall a tick apart.
        v_limit_ = std::min(c.v_limit, double(std::numeric_limits<T>::max()));
        u_limit_ = std::min(c.u_limit, double(std::numeric_limits<T>::max()));
        force_ = c.force_input == 1;
        force_limit_ = c.force_limit;
        slip_threshold_ = c.slip_threshold;
        max_hold_ = c.max_hold_ticks;
        // Cascades run in the structure sosfilt would pick for T ("auto": delta
        // sections for float's low-frequency poles, tdf2 otherwise).
        if (c.n_sos_v > 0) rate_f_ = make_cascade(c.sos_v, c.n_sos_v);
        if (use_u_ && c.n_sos_u > 0) rate2_f_ = make_cascade(c.sos_u, c.n_sos_u);
        if (!use_u_) rate2_f_ = make_cascade(c.sos_diff, c.n_sos_diff);
        const auto act = c.activation == 1 ? detector::Activation::fast : detector::Activation::exact;
        if (c.detector_kind == 1) {
            bank_ = std::make_unique<Bank>(c.n_hidden, R_, c.w1, c.b1, c.w2, c.b2, c.input_mean, c.input_gain,
                                           c.fs, c.bank_n_lp, c.bank_lp_taus, c.bank_n_abs, c.bank_abs_taus,
                                           c.bank_load_tau, c.bank_peak_tau, act, c.bank_knee, c.bank_pad_mean == 1);
            mlp_ = &bank_->net();
            undo_bank_.resize(bank_->filter_state_size());
        } else {
            mlp_own_ = std::make_unique<Mlp>(kFeatures, c.n_hidden, R_, c.w1, c.b1, c.w2, c.b2, c.input_mean,
                                             c.input_gain, act);
            mlp_ = mlp_own_.get();
        }
        ctrl_ = StageController(c.controller, c.fs);
        ctrl_kind_ = c.controller.kind;
        shear_w_.resize(nch_);
        for (std::size_t i = 0; i < nch_; ++i)
            shear_w_[i] = c.shear_weights ? c.shear_weights[i] : (i % 2 ? -1.0 : 1.0);
        xin_.resize(n_inputs());
        rate_.resize(nch_);
        rate2_.resize(nch_);
        feat_.resize(std::size_t(R_) * kFeatures);
        det_.resize(std::size_t(R_) * 3);
        out_.resize(n_outputs());
        std::fill(out_.begin(), out_.end(), 0.0);
        for (int r = 0; r < R_; ++r) out_[2 + 3 * r + 1] = 1.0;  // y_non of a silent pad
        if (rate_f_) undo_z1_.resize(rate_f_->raw_state_size());
        if (rate2_f_) undo_z2_.resize(rate2_f_->raw_state_size());
        undo_mlp_.resize(std::size_t(R_));
        undo_feat_.resize(feat_.size());
        undo_det_.resize(det_.size());
        setup_unguarded(c);
        publish_all();
    }

    MirrorPipeline(const MirrorPipeline&) = delete;
    MirrorPipeline& operator=(const MirrorPipeline&) = delete;

    int n_ridges() const noexcept { return R_; }
    double fs() const noexcept { return fs_; }
    bool use_u() const noexcept { return use_u_; }
    std::size_t n_inputs() const noexcept { return n_voltages() + (force_ ? 1 : 0); }
    // The strips' voltages among the inputs (v_out, then u_out when sampled); the force,
    // when there is one, follows them.
    std::size_t n_voltages() const noexcept { return nch_ * (use_u_ ? 2 : 1); }
    bool force_input() const noexcept { return force_; }
    std::size_t n_outputs() const noexcept { return 2 + 3 * std::size_t(R_); }
    std::size_t n_features() const noexcept { return std::size_t(R_) * kFeatures; }
    bool has_rate_filter() const noexcept { return bool(rate_f_); }
    bool has_rate2_filter() const noexcept { return bool(rate2_f_); }
    // 0: the paper's net; 1: the filter-bank net.
    int detector_kind() const noexcept { return bank_ ? 1 : 0; }
    // The detector's inputs per ridge (4, or the bank's: its features, twice that with
    // the pad's mean).
    int n_detector_inputs() const noexcept { return bank_ ? bank_->n_inputs() : kFeatures; }
    ControllerKind controller_kind() const noexcept { return ctrl_kind_; }
    const StageController& controller() const noexcept { return ctrl_; }
    const PipelineStatus& status() const noexcept { return st_; }
    const double* last_output() const noexcept { return out_.data(); }
    const char* simd_path() const noexcept { return simd::isa_name(mlp_->isa()); }
    simd::Isa filter_isa() const noexcept { return filter_isa_; }

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
#ifndef TM_BENCH_NO_GUARDS
        publish();
#endif
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
        publish_all();
        return bad;
    }

    // Back to rest: filters and detector state zero, controller at x0, counters cleared.
    void reset(double x0 = 0.0) noexcept {
        if (rate_f_) rate_f_->reset();
        if (rate2_f_) rate2_f_->reset();
        if (bank_)
            bank_->reset();
        else
            mlp_->reset();
        ctrl_.reset(x0);
        st_ = PipelineStatus{};
        unguarded_left_ = 0;
        for (std::size_t i = 0; i < feat_.size(); ++i) feat_[i] = TD(0);
        for (std::size_t i = 0; i < det_.size(); ++i) det_[i] = TD(0);
        std::fill(out_.begin(), out_.end(), 0.0);
        for (int r = 0; r < R_; ++r) {
            out_[2 + 3 * r + 1] = 1.0;
        }
        f_prev_ = f_new_ = 0.0;
        have_f_ = false;
        out_[0] = ctrl_.command();
        publish_all();
    }

    // Tell the controller where the stage is (m), e.g. after homing; velocity zero.
    void set_position(double x) noexcept {
        ctrl_.set_position(x);
        unguarded_left_ = 0;
        out_[0] = ctrl_.command();
        out_[1] = 0.0;
        publish();
    }

    // The status as of the end of the last step(), process_block(), reset() or
    // set_position(): safe to call from any thread while another one steps.
    PipelineStatus published_status(double* position = nullptr, double* velocity = nullptr) const noexcept {
        return board_.read(position, velocity);
    }

    // Mean time of one step() in ns, measured inside C++ over n_iter ticks on a
    // synthetic input (smooth signals a few percent of the limits), best of
    // `repeats`. All state is restored afterwards. Not real-time (allocates).
    double time_step_ns(long n_iter, int repeats = 5) {
        const std::size_t ni = n_inputs(), period = 1024;
        std::vector<double> x(period * ni), o(out_.size());
        // (the force, if any, is the last input: the same smooth signal, in N)
        for (std::size_t t = 0; t < period; ++t)
            for (std::size_t c = 0; c < ni; ++c)
                x[t * ni + c] = 1e-3 * std::sin(0.01 * double(t) * double(c + 1) + double(c));
        Snapshot snap = save();
        const double best = best_time_ns(n_iter, repeats, [&](long i) {
            step(x.data() + (std::size_t(i) % period) * ni, o.data());
        });
        restore(snap);
        unguarded_left_ = 0;
        publish_all();
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
        if (force_) ok &= std::fabs(x[n_voltages()]) <= force_limit_;
        return ok;
    }

    // Why the samples of a tick are refused and the first bad channel.
    RejectReason classify(const double* x, int* channel) const noexcept {
        const std::size_t ni = n_inputs();
        bool nonfinite = false;
        int first = -1;
        for (std::size_t c = 0; c < ni; ++c) {
            const double lim = c < nch_ ? v_limit_ : (c < n_voltages() ? u_limit_ : force_limit_);
            const bool fin = is_finite(x[c]);
            if (!fin || std::fabs(x[c]) > lim) {
                if (first < 0) first = int(c);
                nonfinite |= !fin;
            }
        }
        *channel = first;
        return nonfinite ? RejectReason::nonfinite : RejectReason::out_of_range;
    }

    void record_rejection(RejectReason why, int channel) noexcept {
        counters_changed_ = true;
        ++st_.rejected;
        if (why == RejectReason::nonfinite)
            ++st_.nonfinite;
        else if (why == RejectReason::out_of_range)
            ++st_.out_of_range;
        else
            ++st_.overflow;
        st_.last_reason = int(why);
        st_.last_bad_tick = std::int64_t(st_.ticks);
        st_.last_bad_channel = channel;
        ++st_.consecutive_rejected;
        if (st_.consecutive_rejected > std::uint64_t(max_hold_)) st_.fault = true;
    }

    // Undo of the estimator and detector part of a tick: copied before the update,
    // loaded back when the update left a non-finite value anywhere.
    TM_ALWAYS_INLINE void save_undo() noexcept {
        if (rate_f_) std::memcpy(undo_z1_.data(), rate_f_->raw_state(), undo_z1_.size() * sizeof(T));
        if (rate2_f_) std::memcpy(undo_z2_.data(), rate2_f_->raw_state(), undo_z2_.size() * sizeof(T));
        mlp_->get_state(undo_mlp_.data());
        if (bank_) std::memcpy(undo_bank_.data(), bank_->filter_state(), undo_bank_.size() * sizeof(TD));
        std::memcpy(undo_feat_.data(), feat_.data(), feat_.size() * sizeof(TD));
        std::memcpy(undo_det_.data(), det_.data(), det_.size() * sizeof(TD));
    }
    void load_undo() noexcept {
        if (rate_f_) rate_f_->load_raw_state(undo_z1_.data());
        if (rate2_f_) rate2_f_->load_raw_state(undo_z2_.data());
        mlp_->set_state(undo_mlp_.data());
        if (bank_) bank_->load_filter_state(undo_bank_.data());
        std::memcpy(feat_.data(), undo_feat_.data(), feat_.size() * sizeof(TD));
        std::memcpy(det_.data(), undo_det_.data(), det_.size() * sizeof(TD));
    }
    // Every value an accepted update wrote is finite: features (the filters'
    // outputs), the filters' states, the detector outputs (y_pred is its state).
    // |v| <= max is false for NaN and +-Inf: one compare per value, vectorised.
    template <typename U>
    static TM_ALWAYS_INLINE bool all_finite(const U* a, std::size_t n) noexcept {
        bool ok = true;
        for (std::size_t i = 0; i < n; ++i) ok &= std::fabs(a[i]) <= std::numeric_limits<U>::max();
        return ok;
    }
    TM_ALWAYS_INLINE bool update_finite() const noexcept {
        bool ok = all_finite(feat_.data(), feat_.size()) && all_finite(det_.data(), det_.size());
        if (bank_) ok &= all_finite(bank_->filter_state(), bank_->filter_state_size());
        if (rate_f_) ok &= all_finite(rate_f_->raw_state(), rate_f_->raw_state_size());
        if (rate2_f_) ok &= all_finite(rate2_f_->raw_state(), rate2_f_->raw_state_size());
        return ok;
    }

    // ---- ticks that cannot overflow: the guard's undo and check are skipped.
    //
    // Per tick, a section with input bounded by u and states bounded by m (both
    // forms, coefficients over a0) gives |y| <= |b0| u + m and new states bounded by
    // alpha m + beta u:
    //   tdf2   y = b0 x + s1, s1' = b1 x - a1 y + s2, s2' = b2 x - a2 y:
    //          alpha = max(1 + |a1|, |a2|), beta = max(|b1| + |a1||b0|, |b2| + |a2||b0|)
    //   delta  y = b0 x + s1, s1' = s1 + B1 x + s2 - A1 y, s2' = s2 + B2 x - A2 y:
    //          alpha = max(2 + |A1|, 1 + |A2|), beta = max(|B1| + |A1||b0|, |B2| + |A2||b0|)
    // (the larger of the two forms is used, whichever runs). The input gain beta
    // (the equaliser's, ~1e8 Pa/s per V) adds to the state bound once per tick
    // instead of multiplying it, so the bounds grow by about alpha <= 3 per tick.
    // Chained through the cascades (a section's input bound is the previous one's
    // output bound; the differentiator's input is the rate) and the controller's
    // asymmetry integrator (|a'| <= |a| + dt sum|w| |rate|, w the shear weights), the
    // bounds after one tick
    // are an affine, non-negative map v' <= M v of v = (section state bounds, |a|, 1)
    // whose input term is the largest accepted sample (input_bound_). The map and
    // its powers M^(2^j) are built at construction; after a guarded, accepted tick
    // the measured bounds are pushed through the powers (binary lifting) to find the
    // largest K <= kMaxUnguarded for which every state, feature and the asymmetry
    // stay below their limits (limit_ keeps the detector's arithmetic finite too).
    // The bounds only grow with K (alpha >= 1), so the next K ticks whose samples
    // are at most input_bound_ cannot overflow and skip the undo and the check; a
    // reset or any guarded tick starts a new count.
    static constexpr double kUnguardedInput = 1e100;
    static constexpr int kLiftLevels = 12;  // K <= 2^12 - 1
    static constexpr double kAsymLimit = 1e300;
    static constexpr double kRoundingMargin = 1.0 + 1e-4;  // T arithmetic and T-rounded coefficients
    static constexpr double kRefSlack = 16.0;  // a reused window costs log_alpha(16), 2-3 ticks
    static void section_bound(const double* s, double* alpha, double* beta, double* b0_abs) noexcept {
        const double a0 = s[3];
        const double b0 = s[0] / a0, b1 = s[1] / a0, b2 = s[2] / a0, a1 = s[4] / a0, a2 = s[5] / a0;
        const double B1 = 2.0 * b0 + b1, B2 = (b0 + b1) + b2, A1 = 2.0 + a1, A2 = (1.0 + a1) + a2;
        const double ab0 = std::fabs(b0);
        const double al_t = std::max(1.0 + std::fabs(a1), std::fabs(a2));
        const double be_t = std::max(std::fabs(b1) + std::fabs(a1) * ab0, std::fabs(b2) + std::fabs(a2) * ab0);
        const double al_d = std::max(2.0 + std::fabs(A1), 1.0 + std::fabs(A2));
        const double be_d = std::max(std::fabs(B1) + std::fabs(A1) * ab0, std::fabs(B2) + std::fabs(A2) * ab0);
        *alpha = std::max(al_t, al_d) * kRoundingMargin;
        *beta = std::max(be_t, be_d) * kRoundingMargin;
        *b0_abs = ab0 * kRoundingMargin;
    }
    void setup_unguarded(const PipelineConfig& c) {
        lift_dim_ = 0;  // 0: never unguarded
        // Detector: |xn| <= (m + |mean|) |gain|; a hidden unit sums nf of them times w1.
        const int nf = detector_input_count(c);
        double gmax = 1.0, mean = 0.0;
        for (int h = 0; h < c.n_hidden; ++h) {
            double row = 0.0;
            for (int i = 0; i < nf; ++i) row += std::fabs(c.w1[(nf + 1) * h + i] * c.input_gain[i]);
            gmax = std::max(gmax, row);
        }
        for (int i = 0; i < nf; ++i) mean = std::max(mean, std::fabs(c.input_mean[i]));
        limit_ = std::min(double(std::numeric_limits<T>::max()), double(std::numeric_limits<TD>::max())) * 1e-6 / gmax;
        // The accepted samples' bound: the sample limits, or where the arithmetic's range
        // allows larger limits (float64 throughout), kUnguardedInput checked per tick.
        const double lim = std::max(c.v_limit, c.use_u ? c.u_limit : 0.0);
        input_bound_ = limit_ > kUnguardedInput * 1e6 ? std::min(lim, kUnguardedInput) : lim;
        inputs_bounded_ = c.v_limit <= input_bound_ && (!c.use_u || c.u_limit <= input_bound_);
        if (!(input_bound_ > 0.0 && std::isfinite(input_bound_))) return;
        if (!(limit_ > 1e6 * (mean + 1.0) && limit_ > input_bound_ * 1e6)) return;

        const int n1 = c.n_sos_v, n2 = c.use_u ? c.n_sos_u : c.n_sos_diff;
        // State bounds: the sections', the filter bank's (one for all its states), |a|, 1.
        const std::size_t nb = bank_ ? 1 : 0;
        const std::size_t d = std::size_t(n1 + n2) + nb + 2, ib = std::size_t(n1 + n2), ia = d - 2, ic = d - 1;
        using Row = std::vector<double>;
        auto unit = [&](std::size_t j, double v = 1.0) {
            Row r(d, 0.0);
            r[j] = v;
            return r;
        };
        auto axpy = [](double a, const Row& x, Row y) {
            for (std::size_t j = 0; j < y.size(); ++j) y[j] += a * x[j];
            return y;
        };
        std::vector<double> m(d * d, 0.0);
        // One cascade: rows of its sections' state bounds; returns its output's bound.
        auto cascade = [&](const double* sos, int n, std::size_t first, Row u) {
            for (int i = 0; i < n; ++i) {
                double alpha, beta, b0;
                section_bound(sos + 6 * i, &alpha, &beta, &b0);
                const std::size_t j = first + std::size_t(i);
                const Row next = axpy(beta, u, unit(j, alpha));
                std::copy(next.begin(), next.end(), m.begin() + std::ptrdiff_t(j * d));
                Row y = unit(j);
                u = axpy(b0, u, y);
            }
            return u;
        };
        const Row x = unit(ic, input_bound_ * kRoundingMargin);
        const Row f1 = n1 > 0 ? cascade(c.sos_v, n1, 0, x) : x;
        const Row f2 = c.use_u ? (n2 > 0 ? cascade(c.sos_u, n2, std::size_t(n1), x) : x)
                               : cascade(c.sos_diff, n2, std::size_t(n1), f1);
        double wsum = 0.0;  // |shear signal| <= sum |w| * (the rates' bound)
        for (int i = 0; i < 2 * c.n_ridges; ++i) wsum += c.shear_weights ? std::fabs(c.shear_weights[i]) : 1.0;
        // With a load cell: |a'| <= |a| + |F - F_prev| <= |a| + 2 force_limit.
        const Row arow = c.force_input == 1 ? axpy(2.0 * c.force_limit * kRoundingMargin, unit(ic), unit(ia))
                                            : axpy(wsum / fs_ * kRoundingMargin, f1, unit(ia));
        // The velocity law multiplies a by its shear gain and the shear signal's input by
        // rate_gain: with extreme gains those products overflow (inf - inf: a NaN command)
        // before |a| reaches its limit. The window keeps g |a| below kAsymLimit, and is never
        // opened when rate_gain times the input's bound could overflow.
        const ControllerParams& law = c.controller;
        const bool vel = law.kind == ControllerKind::velocity;
        const double g_a = vel ? law.shear_gain * (1.0 + law.pred_boost) : 0.0;
        const double in_max = c.force_input == 1 ? 2.0 * c.force_limit * fs_ : wsum * limit_;
        if (vel && !(law.rate_gain * in_max < kAsymLimit)) return;
        asym_limit_ = g_a > 1.0 ? kAsymLimit / g_a : kAsymLimit;
        std::copy(arow.begin(), arow.end(), m.begin() + std::ptrdiff_t(ia * d));
        if (bank_) {
            // Every bank state z is a low-pass (a z + (1 - a) x, a in [0, 1)), a leaky
            // integral (b z + x / fs) or a decaying peak (max(|load|, c z)) of
            // x in {d, s, |d|}, |x| <= 2 (the rates' bound): so |z'| <= |z| + 2 max(1, 1/fs)
            // (the rates' bound), whatever the time constants.
            const Row brow = axpy(2.0 * std::max(1.0, 1.0 / fs_) * kRoundingMargin, f1, unit(ib, kRoundingMargin));
            std::copy(brow.begin(), brow.end(), m.begin() + std::ptrdiff_t(ib * d));
        }
        m[ic * d + ic] = 1.0;
        for (double v : m)
            if (!std::isfinite(v)) return;
        // Limits: every state bound, both features and the asymmetry.
        lift_check_.assign(m.size() + 2 * d, 0.0);
        lift_limit_.assign(d + 1, limit_);
        for (std::size_t j = 0; j + 2 < d; ++j) lift_check_[j * d + j] = 1.0;
        std::copy(f1.begin(), f1.end(), lift_check_.begin() + std::ptrdiff_t(ia * d));
        lift_check_[ic * d + ia] = 1.0;
        lift_limit_[ia] = limit_;
        lift_limit_[ic] = asym_limit_;
        std::copy(f2.begin(), f2.end(), lift_check_.begin() + std::ptrdiff_t(d * d));
        lift_limit_[d] = limit_;
        // M^(2^j) by squaring.
        lift_pow_.assign(std::size_t(kLiftLevels) * d * d, 0.0);
        std::copy(m.begin(), m.end(), lift_pow_.begin());
        for (int l = 1; l < kLiftLevels; ++l) {
            const double* p = lift_pow_.data() + std::size_t(l - 1) * d * d;
            double* q = lift_pow_.data() + std::size_t(l) * d * d;
            for (std::size_t i = 0; i < d; ++i)
                for (std::size_t k = 0; k < d; ++k) {
                    const double pik = p[i * d + k];
                    if (pik != 0.0)
                        for (std::size_t j = 0; j < d; ++j) q[i * d + j] += pik * p[k * d + j];
                }
        }
        lift_v_.assign(d, 0.0);
        lift_w_.assign(d, 0.0);
        lift_u_.assign(d, 0.0);
        lift_ref_.assign(d, 0.0);
        lift_ref_k_ = 0;
        lift_sections_[0] = std::size_t(n1);
        lift_sections_[1] = std::size_t(n2);
        lift_bank_ = ib;
        lift_dim_ = d;
    }
    // Largest |value| of each section's two states (the raw layout is section-major).
    void section_bounds(const SosCascade<T>* f, double* out) const noexcept {
        const std::size_t n = f->sections(), per = f->raw_state_size() / n;
        const T* z = f->raw_state();
        for (std::size_t s = 0; s < n; ++s) out[s] = max_abs(z + s * per, per);
    }
    bool lift_within(const double* v) const noexcept {
        const std::size_t d = lift_dim_;
        bool ok = true;
        for (std::size_t r = 0; r <= d; ++r) {
            double acc = 0.0;
            for (std::size_t j = 0; j < d; ++j) acc += lift_check_[r * d + j] * v[j];
            ok &= acc <= lift_limit_[r];  // false for NaN
        }
        return ok;
    }
    // After an accepted tick (a guarded one, or the last of a window): how many
    // ticks may skip the undo. The window found for bounds lift_ref_ holds for any
    // smaller bounds (the map is monotone), so it is reused while the measured
    // bounds stay below them; otherwise a new window is lifted for the measured
    // bounds times kRefSlack.
    __attribute__((noinline)) void renew_unguarded() noexcept {
        unguarded_left_ = 0;
        const std::size_t d = lift_dim_;
        if (d == 0) return;
        double* v = lift_v_.data();
        if (rate_f_) section_bounds(rate_f_.get(), v);
        if (rate2_f_) section_bounds(rate2_f_.get(), v + lift_sections_[0]);
        if (bank_) v[lift_bank_] = max_abs(bank_->filter_state(), bank_->filter_state_size());
        v[d - 2] = std::fabs(ctrl_.asymmetry());
        v[d - 1] = 1.0;
        bool below = lift_ref_k_ != 0;
        for (std::size_t i = 0; i < d; ++i) below &= v[i] <= lift_ref_[i];
        if (below) {
            unguarded_left_ = lift_ref_k_;
            return;
        }
        for (std::size_t i = 0; i + 1 < d; ++i) lift_ref_[i] = v[i] * kRefSlack;
        lift_ref_[d - 1] = 1.0;
        lift_ref_k_ = lift(lift_ref_.data());
        unguarded_left_ = lift_ref_k_ != 0 ? lift_ref_k_ : lift(v);  // near the limits: no slack
    }
    // The largest K < 2^kLiftLevels for which K ticks from the bounds v0 keep every
    // bound below its limit; 0 if v0 itself is not.
    std::uint32_t lift(const double* v0) noexcept {
        const std::size_t d = lift_dim_;
        double* v = lift_u_.data();
        double* w = lift_w_.data();
        std::copy(v0, v0 + d, v);
        if (!lift_within(v)) return 0;
        std::uint32_t k = 0;
        for (int l = kLiftLevels - 1; l >= 0; --l) {
            const double* p = lift_pow_.data() + std::size_t(l) * d * d;
            for (std::size_t i = 0; i < d; ++i) {
                double acc = 0.0;
                for (std::size_t j = 0; j < d; ++j) acc += p[i * d + j] * v[j];
                w[i] = acc;
            }
            if (lift_within(w)) {
                std::copy(w, w + d, v);
                k += std::uint32_t(1) << l;
            }
        }
        return k;
    }
    template <typename U>
    static double max_abs(const U* a, std::size_t n) noexcept {
        double m = 0.0;
        for (std::size_t i = 0; i < n; ++i) m = std::max(m, double(std::fabs(a[i])));
        return m;
    }
    TM_ALWAYS_INLINE bool inputs_small(const double* x) const noexcept {
        if (inputs_bounded_) return true;  // the sample limits already bound them
        bool ok = true;  // (the voltages: a force enters the bounds by its own limit)
        for (std::size_t c = 0, n = n_voltages(); c < n; ++c) ok &= std::fabs(x[c]) <= input_bound_;
        return ok;
    }

    // The controller on the detector outputs: fresh ones on an accepted tick, the
    // held ones (and no new asymmetry) on a rejected tick.
    TM_ALWAYS_INLINE void drive(bool accepted, bool* slip_now) noexcept {
        double y = 0.0, ys = 0.0, asym = 0.0;
        for (int r = 0; r < R_; ++r) {
            const TD* d = det_.data() + 3 * r;
            ys = std::max(ys, double(d[0]));
            y = std::max(y, double(d[2]));
        }
        if (force_) {
            // With a load cell the shear signal is the force's change: (F - F_prev) fs, so
            // that the integrator holds the force since the tare. Across rejected ticks
            // F_prev is the last accepted force, and the integral stays whole.
            asym = have_f_ ? (f_new_ - f_prev_) * fs_ : 0.0;
        } else {
            for (int r = 0; r < R_; ++r)
                asym += shear_w_[2 * r] * double(feat_[kFeatures * r + 0]) +
                        shear_w_[2 * r + 1] * double(feat_[kFeatures * r + 1]);
        }
        const bool slip = accepted ? ys >= slip_threshold_ : st_.slip;
        const bool fault = accepted ? false : st_.fault;
        *slip_now = slip;
        if (!accepted) asym = 0.0;  // no new rate information: the integrator only leaks
        if (fault) y = 0.0;
        if (ctrl_kind_ != ControllerKind::none) ctrl_.step(y, asym, fault, slip);
    }

    // One tick. A tick is accepted only if its samples are valid and every state it
    // updates (filters, detector, controller) stays finite; otherwise all of them
    // are what they were before it, and it is counted with its reason.
    //
    // The common tick, valid samples inside a window that cannot overflow
    // (renew_unguarded), runs inline with no undo and no check; every other tick
    // (the first after a window, a reset, bad or large samples) takes the guarded
    // path, out of line so that it does not crowd the common one.
    //
    // TM_BENCH_NO_GUARDS (never in a shipped build) compiles the common tick without
    // the overflow guard's window and step() without publishing the status, so that
    // bench/soak.py can time what the guards cost on today's kernels.
    TM_ALWAYS_INLINE bool tick(const double* x) noexcept {
#ifdef TM_BENCH_NO_GUARDS
        if (samples_ok(x)) {
            estimate(x);
            detect();
            bool slip = false;
            drive(true, &slip);
            accept(slip);
            finish_tick();
            return true;
        }
#endif
        if (unguarded_left_ != 0 && samples_ok(x) && inputs_small(x)) {
            estimate(x);
            detect();
            bool slip = false;
            drive(true, &slip);  // cannot overflow: renew_unguarded bounds its input
            accept(slip);
            finish_tick();
            // The window's last tick: a new window from the states it left (all finite).
            if (--unguarded_left_ == 0) renew_unguarded();
            return true;
        }
        return tick_guarded(x);
    }
    __attribute__((noinline)) bool tick_guarded(const double* x) noexcept {
        RejectReason why = RejectReason::none;
        int channel = -1;
        bool slip = false;
        if (!samples_ok(x)) why = classify(x, &channel);
        if (why == RejectReason::none) {
            const bool guarded = unguarded_left_ == 0 || !inputs_small(x);
            if (guarded) save_undo();
            estimate(x);
            detect();
            if (guarded && !update_finite()) {
                load_undo();
                why = RejectReason::overflow;
            } else if (!guarded) {
                drive(true, &slip);  // cannot overflow: renew_unguarded bounds its input
            } else {
                const typename StageController::State before = ctrl_.state();
                drive(true, &slip);
                if (!ctrl_.state_finite()) {
                    ctrl_.set_state(before);
                    load_undo();
                    why = RejectReason::overflow;
                }
            }
            if (why == RejectReason::none && (guarded || --unguarded_left_ == 0)) renew_unguarded();
        }
        if (why == RejectReason::none) {
            accept(slip);
        } else {
            record_rejection(why, channel);
            drive(false, &slip);
        }
        finish_tick();
        return why == RejectReason::none;
    }
    TM_ALWAYS_INLINE void accept(bool slip) noexcept {
        if (force_) {
            f_prev_ = f_new_;
            have_f_ = true;
        }
        counters_changed_ |= st_.consecutive_rejected != 0;
        st_.consecutive_rejected = 0;
        st_.fault = false;
        st_.slip = slip;
        for (std::size_t i = 0; i < det_.size(); ++i) out_[2 + i] = double(det_[i]);
    }
    TM_ALWAYS_INLINE void finish_tick() noexcept {
        out_[0] = ctrl_.command();
        out_[1] = ctrl_.velocity();
        st_.at_limit = ctrl_kind_ != ControllerKind::none && ctrl_.at_limit();
        ++st_.ticks;
    }

    // The status for other threads. Per tick only the words a tick always changes,
    // plus the counters when a rejection or a recovery changed them.
    void publish() noexcept {
        board_.publish(st_, ctrl_.command(), ctrl_.velocity(), counters_changed_);
        counters_changed_ = false;
    }
    void publish_all() noexcept {
        counters_changed_ = true;
        publish();
    }

    // Features -> detector outputs (n_ridges, 3): one branch, the same every tick.
    TM_ALWAYS_INLINE void detect() noexcept {
        if (bank_)
            bank_->step(feat_.data(), det_.data());
        else
            mlp_->step(feat_.data(), det_.data());
    }

    // Samples -> features (n_ridges, 4).
    TM_ALWAYS_INLINE void estimate(const double* x) noexcept {
        if (force_) f_new_ = x[n_voltages()];
        const T* xv;
        const T* xu;
        if constexpr (std::is_same<T, double>::value) {
            xv = x;
            xu = x + nch_;
        } else {
            const std::size_t ni = n_voltages();  // (the force stays double: it may exceed float's range)
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
        std::vector<TD> mlp, bank, feat, det;
        std::vector<double> out;
        StageController ctrl;
        PipelineStatus st;
        double f_prev = 0.0;
        bool have_f = false;
    };
    Snapshot save() const {
        Snapshot s;
        // The raw states, bit for bit (get_state's scipy layout is not exact for float delta
        // sections: time_step_ns changed a float32 pipeline's next outputs by 6e-8).
        if (rate_f_) s.z1.assign(rate_f_->raw_state(), rate_f_->raw_state() + rate_f_->raw_state_size());
        if (rate2_f_) s.z2.assign(rate2_f_->raw_state(), rate2_f_->raw_state() + rate2_f_->raw_state_size());
        s.mlp.resize(std::size_t(R_));
        mlp_->get_state(s.mlp.data());
        if (bank_) s.bank.assign(bank_->filter_state(), bank_->filter_state() + bank_->filter_state_size());
        s.feat.assign(feat_.data(), feat_.data() + feat_.size());
        s.det.assign(det_.data(), det_.data() + det_.size());
        s.out = out_;
        s.ctrl = ctrl_;
        s.st = st_;
        s.f_prev = f_prev_;
        s.have_f = have_f_;
        return s;
    }
    void restore(const Snapshot& s) noexcept {
        if (rate_f_) rate_f_->load_raw_state(s.z1.data());
        if (rate2_f_) rate2_f_->load_raw_state(s.z2.data());
        mlp_->set_state(s.mlp.data());
        if (bank_) bank_->load_filter_state(s.bank.data());
        std::copy(s.feat.begin(), s.feat.end(), feat_.data());
        std::copy(s.det.begin(), s.det.end(), det_.data());
        out_ = s.out;
        ctrl_ = s.ctrl;
        st_ = s.st;
        f_prev_ = s.f_prev;
        have_f_ = s.have_f;
    }

    int R_ = 0;
    std::size_t nch_ = 0;
    double fs_ = 0.0;
    bool use_u_ = true;
    double v_limit_ = 0.0, u_limit_ = 0.0, slip_threshold_ = 0.8;
    long max_hold_ = 0;
    bool force_ = false;        // a load cell's force is the last input (force_input)
    double force_limit_ = 0.0;  // N
    double f_new_ = 0.0, f_prev_ = 0.0;  // this tick's force; the last accepted one
    bool have_f_ = false;                // f_prev_ holds an accepted force
    std::unique_ptr<SosCascade<T>> rate_f_, rate2_f_;
    simd::Isa filter_isa_ = simd::detect_isa();  // the cascades' variant, chosen when they are built
    std::unique_ptr<Mlp> mlp_own_;  // the paper's net (detector_kind 0)
    std::unique_ptr<Bank> bank_;    // the filter-bank net (detector_kind 1)
    Mlp* mlp_ = nullptr;            // the net that runs: mlp_own_ or the bank's
    StageController ctrl_;
    ControllerKind ctrl_kind_ = ControllerKind::none;
    AlignedBuffer<T> xin_, rate_, rate2_;
    AlignedBuffer<TD> feat_, det_;
    AlignedBuffer<T> undo_z1_, undo_z2_;
    AlignedBuffer<TD> undo_mlp_, undo_bank_, undo_feat_, undo_det_;
    std::vector<double> out_;
    std::vector<double> shear_w_;  // (n_ridges, 2): weights of rate_L, rate_R in the shear signal
    PipelineStatus st_;
    StatusBoard board_;
    bool counters_changed_ = true;  // a counter of st_ changed since the last publication
    // Ticks that cannot overflow (setup_unguarded, renew_unguarded).
    double limit_ = 0.0, input_bound_ = kUnguardedInput;
    double asym_limit_ = kAsymLimit;  // |a| within a window (kAsymLimit over the law's shear gain)
    bool inputs_bounded_ = false;
    std::uint32_t unguarded_left_ = 0;
    std::size_t lift_dim_ = 0;      // d: section bounds, (bank bound), |asymmetry|, 1; 0: always guarded
    std::size_t lift_sections_[2] = {0, 0};
    std::size_t lift_bank_ = 0;       // index of the filter bank's bound (with a bank)
    std::vector<double> lift_pow_;    // kLiftLevels matrices M^(2^l), d x d
    std::vector<double> lift_check_;  // (d + 1) x d rows bounded by lift_limit_
    std::vector<double> lift_limit_;
    std::vector<double> lift_v_, lift_w_, lift_u_;
    std::vector<double> lift_ref_;  // bounds whose window lift_ref_k_ is known
    std::uint32_t lift_ref_k_ = 0;
};

}  // namespace tactile
