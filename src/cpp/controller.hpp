// The stage controller of the real-time pipeline: its parameters (the one list of
// their names, defaults and laws that the C ABI, the bindings and the Python
// dataclasses share), their validation, and the control laws (StageController).
//
// Controllers (y = max over ridges of y_pred, dt = 1/fs, dir in {-1, 0, +1}):
//
//   direction  a <- exp(-dt/asym_tau) a + dt * sum_r (rate_L,r - rate_R,r): a leaky
//              integral of the stress-rate asymmetry, i.e. the L/R stress difference
//              (shear load) high-passed at 1/(2 pi asym_tau). With shear_weights w the
//              sum is sum_r (w_2r rate_L,r + w_2r+1 rate_R,r): a calibrated combination of
//              the strips that stays monotonic in the shear where the plain L-R
//              difference turns back (loop.experiment.calibrate_shear_weights). dir = direction_sign *
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
// tared again (the re-stuck contact is the new reference). A report starts it once it
// lasted slip_confirm and while |a| >= slip_min_asym; a type-2 integral at v_max (a
// run-away) starts it at once.
//
// Command (both laws): the law's position x, or, with planner_decel = d > 0 (a stage whose
// move command plans a braking move to the target, at its deceleration d), x led by the
// braking distance sign(v) max(0, v^2 / (2 d) - |v| dt / 2): such a planner then moves its
// set point at the law's speed v instead of trailing by v^2 / (2 d) with a lag |v| / d
// (StageController::command). Clipped to the travel.
//
// Arming (both laws): for the first arm_delay seconds after a reset the command holds
// (the finger settles on the pad); at the end the asymmetry integrator is zeroed, so the
// shear of the settled contact is the reference (a tare).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "simd.hpp"

namespace tactile {

enum class ControllerKind : int { none = 0, paper = 1, velocity = 2 };

inline const char* controller_name(ControllerKind k) noexcept {
    switch (k) {
        case ControllerKind::paper: return "paper";
        case ControllerKind::velocity: return "velocity";
        default: return "none";
    }
}

// The controller parameters: the one definition of their names, defaults and the
// laws that read them. The C struct tm_controller_params (tm.h), the pybind11
// dictionaries and the Python dataclasses (loop/controller.py, through
// _core.controller_fields()) are all built from this list.
//   X(name, default, laws, meaning)   laws: bit 1 paper, bit 2 velocity (3: both)
// The velocity law starts its ramp lower than the paper law's threshold: its
// default threshold is kVelocityThreshold (see default_controller()).
#define TM_CONTROLLER_FIELDS(X)                                                                           \
    X(threshold, 0.5, 3, "y_pred threshold (paper) / start of the speed ramp (velocity), [0, 1)")        \
    X(gain, 0.01, 1, "paper: m/s of target motion per unit y_pred, >= 0")                                 \
    X(y_full, 0.7, 2, "velocity: y_pred giving full speed, (threshold, 1]")                              \
    X(v_max, 0.02, 2, "velocity: speed limit, m/s, > 0")                                                  \
    X(a_max, 1.0, 2, "velocity: acceleration limit, m/s^2, > 0")                                          \
    X(x_min, -0.05, 3, "lower travel limit, m, <= 0")                                                     \
    X(x_max, 0.05, 3, "upper travel limit, m, >= 0")                                                      \
    X(direction_sign, 1.0, 3, "+1 or -1: stage direction for a positive L-R asymmetry")                   \
    X(asym_tau, 1.0, 3, "s, > 0: time constant of the asymmetry integrator")                               \
    X(asym_deadband, 0.0, 3, ">= 0: |asymmetry| below this keeps the previous direction (rate units x s)") \
    X(shear_gain, 0.0, 2, "velocity: m/s per unit of asymmetry (shear feedback), >= 0; 0 = off")          \
    X(arm_delay, 0.0, 3, "s after a reset during which the stage holds; then the asymmetry is tared")     \
    X(ramp_gain, 1.0, 2, "velocity: share of v_max commanded by the y_pred ramp, >= 0; 0 = no ramp")      \
    X(pred_boost, 0.0, 2, "velocity: shear gain x (1 + pred_boost * ramp(y_pred)), >= 0")                 \
    X(slip_hold, 0.0, 3, "s, >= 0: on detected slip hold the stage, re-tare this long after (0 = off)")  \
    X(shear_integral, 0.0, 2, "velocity: 1/s, >= 0: integral of the shear feedback (type-2 loop); 0 = off") \
    X(rate_gain, 0.0, 2, "velocity: m/s per unit of L-R stress rate (relative-velocity feedback), >= 0")  \
    X(slip_confirm, 0.0, 3, "s, >= 0: a detected slip starts the slip guard once it lasted this long (0 = at once)") \
    X(slip_min_asym, 0.0, 3, ">= 0: a detected slip starts the slip guard only while |asymmetry| >= this (0 = always)")

// Parameters added after tm_controller_params stopped being the last member of tm_config
// (ABI 5 appended fields behind it): the C ABI carries these as fields of tm_config itself,
// appended at its end, so that every older layout stays valid. Everywhere else (the
// pipeline, the bindings, the Python dataclasses) they are controller parameters like the
// others.
#define TM_CONTROLLER_TAIL_FIELDS(X)                                                                      \
    X(planner_decel, 0.0, 3, "m/s^2, >= 0: the stage plans a braking move to each target at this rate; the command leads by the braking distance (0 = the stage follows the command)")

#define TM_CONTROLLER_ALL_FIELDS(X) TM_CONTROLLER_FIELDS(X) TM_CONTROLLER_TAIL_FIELDS(X)

struct ControllerParams {
    ControllerKind kind = ControllerKind::none;
#define TM_CONTROLLER_MEMBER(name, def, laws, doc) double name = def;
    TM_CONTROLLER_ALL_FIELDS(TM_CONTROLLER_MEMBER)
#undef TM_CONTROLLER_MEMBER
};

constexpr double kVelocityThreshold = 0.3;

// The defaults of a law: what tm_controller_defaults(), the Python dataclasses and
// the reference pipeline all start from.
inline ControllerParams default_controller(ControllerKind k) noexcept {
    ControllerParams p;
    p.kind = k;
    if (k == ControllerKind::velocity) p.threshold = kVelocityThreshold;
    return p;
}

// Name, member and laws of every parameter, in declaration order.
struct ControllerField {
    const char* name;
    double ControllerParams::*member;
    int laws;
    const char* doc;
};
inline const ControllerField* controller_fields(std::size_t* n) noexcept {
#define TM_CONTROLLER_ENTRY(name, def, laws, doc) {#name, &ControllerParams::name, laws, doc},
    static const ControllerField fields[] = {TM_CONTROLLER_ALL_FIELDS(TM_CONTROLLER_ENTRY)};
#undef TM_CONTROLLER_ENTRY
    *n = sizeof fields / sizeof fields[0];
    return fields;
}

// Throws std::invalid_argument naming the first parameter out of its range.
inline void validate_controller(const ControllerParams& c) {
    auto bad = [](const char* name, const std::string& why) {
        throw std::invalid_argument(std::string("controller.") + name + " " + why);
    };
    const int k = static_cast<int>(c.kind);
    if (k < 0 || k > 2) bad("kind", "must be 0 (none), 1 (paper) or 2 (velocity)");
    std::size_t nf = 0;
    const ControllerField* fields = controller_fields(&nf);
    for (std::size_t i = 0; i < nf; ++i)
        if (!std::isfinite(c.*(fields[i].member))) bad(fields[i].name, "must be finite");
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
    if (!(c.shear_integral >= 0.0)) bad("shear_integral", "must be >= 0 (1/s)");
    if (!(c.rate_gain >= 0.0)) bad("rate_gain", "must be >= 0 (m/s per unit of stress rate)");
    if (!(c.slip_confirm >= 0.0 && c.slip_confirm <= 3600.0)) bad("slip_confirm", "must lie in [0, 3600] s");
    if (!(c.slip_min_asym >= 0.0)) bad("slip_min_asym", "must be >= 0 (rate units x s)");
    if (!(c.planner_decel >= 0.0)) bad("planner_decel", "must be >= 0 (m/s^2; 0 = off)");
}


// Stage command from the detector. Double precision whatever the pipeline's T.
class StageController {
public:
    StageController() = default;
    StageController(const ControllerParams& p, double fs) : p_(p), dt_(1.0 / fs) {
        validate_controller(p);
        leak_ = std::exp(-dt_ / p.asym_tau);
        arm_ticks_ = static_cast<std::uint64_t>(std::llround(p.arm_delay * fs));
        hold_ticks_ = static_cast<std::uint64_t>(std::llround(p.slip_hold * fs));
        confirm_ticks_ = static_cast<std::uint64_t>(std::llround(p.slip_confirm * fs));
    }

    // y: max y_pred of the ridges; asym: the shear signal (sum over ridges of
    // rate_L - rate_R, or the pipeline's shear_weights combination);
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
        bool hold = false;
        if (hold_ticks_ > 0) {
            // The integral at the speed limit is a run-away (the shear loop acting on a
            // sliding contact's inverted asymmetry) or a finger the stage cannot follow:
            // either way, guard as after a detected slip.
            const bool runaway = p_.shear_integral > 0.0 && std::fabs(w_) >= p_.v_max;
            // A detected slip counts once reported on confirm_ticks_ + 1 ticks in a row and
            // only while the shear signal is at least slip_min_asym from its tare: the
            // detector raises y_slip for a few ticks at the fastest changes of the shear
            // while the contact sticks, and a contact near its tare cannot slip; stopping
            // a stage that follows a moving finger on such a report makes the slip.
            slip_run_ = slip ? slip_run_ + 1 : 0;
            const bool loaded = std::fabs(a_) >= p_.slip_min_asym;
            if ((slip && loaded && slip_run_ > confirm_ticks_) || runaway) hold_left_ = hold_ticks_;
            if (hold_left_ > 0) {
                hold = true;
                y = 0.0;
                asym = 0.0;
                if (--hold_left_ == 0) {
                    a_ = 0.0;
                    dir_ = 0.0;
                }
            }
        }
        // A fault (no valid input) or a slip stops the stage and forgets the velocity
        // estimate: while the ridges' edges slide the L/R asymmetry answers with the
        // wrong sign (measured on the FEM pad: the shear loop then drives the stage
        // away at v_max), and a steady slide leaves the stress rates quiet, so no
        // speed learnt before or during the slip can be trusted.
        if (fault || hold) w_ = 0.0;
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
                // Type-2 part: w_ integrates the shear (the relative displacement), so it
                // converges to the finger's speed and a steady motion leaves no error;
                // clipped to v_max (anti-windup).
                if (!fault && !hold) {
                    // at most a_max: w is the stage's speed to be, and the stage cannot
                    // change its speed faster (a faster integral is wind-up)
                    double dw = p_.direction_sign * p_.shear_gain * p_.shear_integral * a_;
                    dw = dw > p_.a_max ? p_.a_max : (dw < -p_.a_max ? -p_.a_max : dw);
                    w_ += dt_ * dw;
                    w_ = w_ > p_.v_max ? p_.v_max : (w_ < -p_.v_max ? -p_.v_max : w_);
                }
                double vd = 0.0;
                if (!fault && !hold)
                    vd = dir_ * p_.ramp_gain * p_.v_max * s + w_ +
                         p_.direction_sign * (g * a_ + p_.rate_gain * asym);
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
        w_ = 0.0;
        ticks_ = 0;
        hold_left_ = 0;
        slip_run_ = 0;
    }
    void set_position(double x) noexcept {
        x_ = clamp(x);
        v_ = 0.0;
    }
    double position() const noexcept { return x_; }
    double velocity() const noexcept { return v_; }
    // What goes to the stage. A stage that plans a move to each target (a point-to-point
    // trajectory generator braking at planner_decel, as SimulatedStage and most stage
    // controllers' move commands do) moves its set point at the speed that still stops on
    // the target, sqrt(h^2 + 2 d e) - h with h = d dt / 2 and e the distance left: tracking a
    // target that moves at v it trails by v^2 / (2 d), and its small-signal lag is a time
    // constant |v| / d (20 ms at 20 mm/s and 1 m/s^2; measured on SimulatedStage: 55 degrees
    // more phase at 25 Hz than the data sheet's delay and lag). Leading the target by the
    // braking distance, e = v dt + lead = v^2 / (2 d) + v dt / 2, makes that speed exactly
    // v: the set point moves with the law and the stage is its delay and lag again.
    double command() const noexcept {
        if (!(p_.planner_decel > 0.0) || v_ == 0.0) return x_;
        const double s = std::fabs(v_);
        const double lead = s * s / (2.0 * p_.planner_decel) - 0.5 * s * dt_;
        if (!(lead > 0.0)) return x_;
        return clamp(v_ > 0.0 ? x_ + lead : x_ - lead);
    }
    double asymmetry() const noexcept { return a_; }
    double direction() const noexcept { return dir_; }
    bool at_limit() const noexcept { return x_ <= p_.x_min || x_ >= p_.x_max; }
    const ControllerParams& params() const noexcept { return p_; }
    double velocity_estimate() const noexcept { return w_; }
    bool state_finite() const noexcept { return is_finite(x_) && is_finite(v_) && is_finite(a_) && is_finite(w_); }

    // The mutable state, for a tick's undo.
    struct State {
        double x, v, a, dir, w;
        std::uint64_t ticks, hold_left, slip_run;
    };
    State state() const noexcept { return {x_, v_, a_, dir_, w_, ticks_, hold_left_, slip_run_}; }
    void set_state(const State& s) noexcept {
        w_ = s.w;
        x_ = s.x;
        v_ = s.v;
        a_ = s.a;
        dir_ = s.dir;
        ticks_ = s.ticks;
        hold_left_ = s.hold_left;
        slip_run_ = s.slip_run;
    }

private:
    double clamp(double x) const noexcept { return x < p_.x_min ? p_.x_min : (x > p_.x_max ? p_.x_max : x); }
    ControllerParams p_{};
    double dt_ = 1e-3, leak_ = 1.0;
    double x_ = 0.0, v_ = 0.0, a_ = 0.0, dir_ = 0.0, w_ = 0.0;
    std::uint64_t ticks_ = 0, arm_ticks_ = 0, hold_ticks_ = 0, hold_left_ = 0;
    std::uint64_t confirm_ticks_ = 0, slip_run_ = 0;  // slip_confirm in ticks; ticks of slip in a row
};

}  // namespace tactile
