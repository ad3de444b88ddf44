// What a pipeline is built from (PipelineConfig) and its validation, shared by every
// binding: the C ABI and the Python module check a configuration with validate_config
// before a pipeline is built from it.
#pragma once

#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <string>

#include "controller.hpp"
#include "detector_bank.hpp"

namespace tactile {

// The front end's output swing: an op-amp on +-15 V rails cannot drive v_out or
// u_out further, so a larger sample is a wiring, ADC or software fault. The default
// v_limit and u_limit (V); +inf is refused.
constexpr double kFrontEndSwing = 15.0;

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
    double v_limit = kFrontEndSwing;  // |v_out| above this (V): rejected; finite
    double u_limit = kFrontEndSwing;
    // detector: nf inputs (4, or the bank's count), + the fed-back y_pred
    int n_hidden = 0;
    const double* w1 = nullptr;    // (n_hidden, nf + 1)
    const double* b1 = nullptr;    // (n_hidden)
    const double* w2 = nullptr;    // (2, n_hidden)
    const double* b2 = nullptr;    // (2)
    const double* input_mean = nullptr;  // (nf)
    const double* input_gain = nullptr;  // (nf)
    // 0: the paper's net on the four rates (nf = 4); 1: the filter-bank net
    // (detector_bank.hpp: the rates plus first-order filters over them, nf =
    // 4 + 2 bank_n_lp + bank_n_abs + 3; time constants in s).
    int detector_kind = 0;
    int bank_n_lp = 0;
    const double* bank_lp_taus = nullptr;   // (bank_n_lp), 1..8
    int bank_n_abs = 0;
    const double* bank_abs_taus = nullptr;  // (bank_n_abs), 0..8
    double bank_load_tau = 0.0;
    double bank_peak_tau = 0.0;
    // (nf) or null: the bank's features compressed to sign(x) log(1 + |x| / knee)
    // before the net reads them (detector_bank.hpp); null: as they are.
    const double* bank_knee = nullptr;
    // 0 or 1: the net also reads the pad's mean of the bank's features (their mean over
    // the ridges, detector_bank.hpp); nf is then twice the features (bank_knee too).
    int bank_pad_mean = 0;
    double weights_fs = 0.0;       // Hz the weights were trained for; must equal fs
    int activation = 0;            // 0 exact, 1 fast
    double slip_threshold = 0.8;
    long max_hold_ticks = 100;
    // The controller's shear signal: sum over ridges of w[2r] rate_L + w[2r+1] rate_R.
    // nullptr: +1, -1 (the L-R stress-rate difference). (n_ridges, 2), finite.
    const double* shear_weights = nullptr;
    ControllerParams controller;
    // 1: one more input after the voltages, the pad's tangential force (N) from a load
    // cell under the pad (or the stage's force readout); the controller's shear signal is
    // then its change per tick times fs (N/s), not the strips' rates. A tick whose force
    // is NaN/Inf or beyond force_limit is rejected like a bad voltage. 0: no force input.
    int force_input = 0;
    double force_limit = 100.0;  // N, in (0, 1e6]
};

// ---- validation shared by every binding -------------------------------------------

inline void check_finite_array(const double* a, std::size_t n, const char* name) {
    for (std::size_t i = 0; i < n; ++i)
        if (!std::isfinite(a[i])) throw std::invalid_argument(std::string(name) + " must be finite");
}

// The detector's inputs per ridge (without the fed-back y_pred); 0 for an unknown kind.
inline int detector_input_count(const PipelineConfig& c) noexcept {
    if (c.detector_kind == 0) return 4;
    if (c.detector_kind == 1)
        return detector::BankJordan<double>::input_count(c.bank_n_lp, c.bank_n_abs, c.bank_pad_mean == 1);
    return 0;
}

inline void validate_config(const PipelineConfig& c) {
    auto bad = [](const std::string& m) { throw std::invalid_argument(m); };
    if (c.n_ridges < 1 || c.n_ridges > 64) bad("n_ridges must lie in [1, 64], got " + std::to_string(c.n_ridges));
    // (at least 1 Hz: the laws divide by fs, and a denormal rate made every command NaN)
    // (and at most 10 MHz: a C caller's 1e300 Hz was accepted, its dt a denormal)
    if (!std::isfinite(c.fs) || !(c.fs >= 1.0 && c.fs <= 1e7)) bad("fs must lie in [1, 1e7] Hz");
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
    if (!std::isfinite(c.v_limit) || !(c.v_limit > 0.0)) bad("v_limit must be a positive finite voltage");
    if (!std::isfinite(c.u_limit) || !(c.u_limit > 0.0)) bad("u_limit must be a positive finite voltage");
    if (c.n_hidden < 1 || c.n_hidden > 1024) bad("n_hidden must lie in [1, 1024]");
    if (c.detector_kind != 0 && c.detector_kind != 1)
        bad("detector_kind must be 0 (the paper's net) or 1 (filter bank), got " + std::to_string(c.detector_kind));
    // (checked whatever the kind: a C caller's 5 here, or knees for the paper's net, were
    // silently ignored)
    if (c.bank_pad_mean != 0 && c.bank_pad_mean != 1)
        bad("bank_pad_mean must be 0 or 1, got " + std::to_string(c.bank_pad_mean));
    if (c.detector_kind != 1 && (c.bank_pad_mean != 0 || c.bank_knee))
        bad("bank_pad_mean and bank_knee belong to the filter-bank net (detector_kind 1)");
    if (c.detector_kind == 1) {
        if (c.bank_n_lp < 1 || c.bank_n_lp > detector::BankJordan<double>::kMaxTaus)
            bad("bank_n_lp must lie in [1, 8]");
        if (c.bank_n_abs < 0 || c.bank_n_abs > detector::BankJordan<double>::kMaxTaus)
            bad("bank_n_abs must lie in [0, 8]");
        auto taus_ok = [&](const double* t, int n, const char* name) {
            if (n > 0 && !t) bad(std::string(name) + " is a null pointer");
            for (int k = 0; k < n; ++k)
                if (!(std::isfinite(t[k]) && t[k] > 0.0)) bad(std::string(name) + " must be positive finite times (s)");
        };
        taus_ok(c.bank_lp_taus, c.bank_n_lp, "bank_lp_taus");
        taus_ok(c.bank_abs_taus, c.bank_n_abs, "bank_abs_taus");
        taus_ok(&c.bank_load_tau, 1, "bank_load_tau");
        taus_ok(&c.bank_peak_tau, 1, "bank_peak_tau");
        if (c.bank_knee) {
            const int nf = detector_input_count(c);
            for (int k = 0; k < nf; ++k)
                if (!(std::isfinite(c.bank_knee[k]) && c.bank_knee[k] > 0.0))
                    bad("bank_knee must be positive finite numbers, one per detector input");
        }
    }
    const std::size_t h = std::size_t(c.n_hidden), nf = std::size_t(detector_input_count(c));
    const double* arrs[] = {c.w1, c.b1, c.w2, c.b2, c.input_mean, c.input_gain};
    const char* names[] = {"w1", "b1", "w2", "b2", "input_mean", "input_gain"};
    const std::size_t sizes[] = {h * (nf + 1), h, 2 * h, 2, nf, nf};
    for (int i = 0; i < 6; ++i) {
        if (!arrs[i]) bad(std::string(names[i]) + " is a null pointer");
        check_finite_array(arrs[i], sizes[i], names[i]);
    }
    if (c.activation != 0 && c.activation != 1) bad("activation must be 0 (exact) or 1 (fast)");
    if (!(c.slip_threshold > 0.0 && c.slip_threshold < 1.0)) bad("slip_threshold must lie in (0, 1)");
    if (c.max_hold_ticks < 0) bad("max_hold_ticks must be >= 0");
    if (c.shear_weights) check_finite_array(c.shear_weights, std::size_t(2 * c.n_ridges), "shear_weights");
    if (c.force_input != 0 && c.force_input != 1) bad("force_input must be 0 or 1, got " + std::to_string(c.force_input));
    // (at most 1 MN: the force's change times fs must stay far from overflow)
    if (!std::isfinite(c.force_limit) || !(c.force_limit > 0.0 && c.force_limit <= 1e6))
        bad("force_limit must lie in (0, 1e6] N");
    validate_controller(c.controller);
}


}  // namespace tactile
