// detector_bank.hpp - the filter-bank slip detector: a bank of first-order IIR
// filters over the stress rates in front of the Jordan MLP kernel (jordan_mlp.hpp).
//
// The paper's net reads [v_L, v_R, u_L, u_R] per ridge and remembers only its own
// y_pred; a slip that creeps in differs from a stop in the recent history of the
// rates. This stage keeps that history in a few filter states (python:
// tactile_mirror.detector.bank, the specification), per ridge and tick, with
// d = v_L - v_R, s = v_L + v_R and a(tau) = exp(-1 / (fs tau)):
//
//     for tau in lp_taus:  lpd = a lpd + (1 - a) d,  lps = a lps + (1 - a) s   (Pa/s)
//     for tau in abs_taus: lpa = a lpa + (1 - a) |d|                          (Pa/s)
//     load  = b load  + d / fs,  press = b press + s / fs,  b = a(load_tau)   (Pa)
//     peak  = max(|load|, c peak),                           c = a(peak_tau)  (Pa)
//
// and runs the Jordan net on [v_L, v_R, u_L, u_R, lpd_1, lps_1, ..., lpa_1, ...,
// load, press, peak]. Ridges are independent.
//
// RTNeural-like: sizes fixed at construction (which may throw); step(), run(), the
// state accessors allocate nothing and throw nothing. Block runs go in chunks of the
// net's chunk_ticks(): the features are written time-contiguous straight into the
// net's staging rows, which its block path normalises in place and runs (JordanMLP::
// run_staged); step() and run() give the same bits.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <stdexcept>

#include "jordan_mlp.hpp"

namespace tactile {
namespace detector {

template <typename T>
class BankJordan {
public:
    static constexpr int n_raw = 4;
    static constexpr int kMaxTaus = 8;
    static constexpr int n_outputs = 3;

    /// Features: 4 + 2 n_lp + n_abs + 3. Weights as JordanMLP with that many inputs.
    static int feature_count(int n_lp, int n_abs) noexcept { return n_raw + 2 * n_lp + n_abs + 3; }

    BankJordan(int n_hidden, int n_ridges, const double* w1, const double* b1, const double* w2, const double* b2,
               const double* input_mean, const double* input_gain, double fs, int n_lp, const double* lp_taus,
               int n_abs, const double* abs_taus, double load_tau, double peak_tau,
               Activation activation = Activation::exact)
        : net_(checked_features(n_lp, n_abs), n_hidden, n_ridges, w1, b1, w2, b2, input_mean, input_gain,
               activation),
          n_r_(n_ridges),
          n_lp_(n_lp),
          n_abs_(n_abs),
          nf_(feature_count(n_lp, n_abs)),
          ns_(2 * n_lp + n_abs + 3) {
        if (!(std::isfinite(fs) && fs > 0)) throw std::invalid_argument("fs must be a positive number of Hz");
        auto leak = [fs](double tau) {
            if (!(std::isfinite(tau) && tau > 0)) throw std::invalid_argument("time constants must be positive s");
            return std::exp(-1.0 / (fs * tau));
        };
        for (int k = 0; k < n_lp; ++k) {
            a_lp_[k] = static_cast<T>(leak(lp_taus[k]));
            g_lp_[k] = static_cast<T>(1.0 - leak(lp_taus[k]));
        }
        for (int k = 0; k < n_abs; ++k) {
            a_abs_[k] = static_cast<T>(leak(abs_taus[k]));
            g_abs_[k] = static_cast<T>(1.0 - leak(abs_taus[k]));
        }
        b_ = static_cast<T>(leak(load_tau));
        c_ = static_cast<T>(leak(peak_tau));
        inv_fs_ = static_cast<T>(1.0 / fs);
        const std::size_t count = std::size_t(n_r_) * ns_ + std::size_t(n_r_) * nf_ + 16;
        void* mem = std::aligned_alloc(64, ((count * sizeof(T) + 63) / 64) * 64);
        if (!mem) throw std::bad_alloc();
        buf_.reset(mem);
        std::memset(mem, 0, count * sizeof(T));
        T* p = static_cast<T*>(mem);
        st_ = p;
        p += std::size_t(n_r_) * ns_;
        feat_ = p;
    }

    int n_hidden() const noexcept { return net_.n_hidden(); }
    int n_ridges() const noexcept { return n_r_; }
    int n_features() const noexcept { return nf_; }
    /// Filter states per ridge (2 n_lp + n_abs + 3).
    int n_state() const noexcept { return ns_; }
    JordanMLP<T>& net() noexcept { return net_; }
    const JordanMLP<T>& net() const noexcept { return net_; }

    /// State: y_pred(t-1) per ridge (n_ridges) and the filter states (n_ridges, n_state) row-major,
    /// in feature order after the four rates.
    void get_state(T* y_pred, T* filt) const noexcept {
        net_.get_state(y_pred);
        for (std::size_t k = 0; k < std::size_t(n_r_) * ns_; ++k) filt[k] = st_[k];
    }
    void set_state(const T* y_pred, const T* filt) noexcept {
        net_.set_state(y_pred);
        for (std::size_t k = 0; k < std::size_t(n_r_) * ns_; ++k) st_[k] = filt[k];
    }
    /// The filter states themselves, (n_ridges, n_state) row-major (the pipeline's
    /// overflow guard reads and restores them in place).
    const T* filter_state() const noexcept { return st_; }
    std::size_t filter_state_size() const noexcept { return std::size_t(n_r_) * ns_; }
    void load_filter_state(const T* filt) noexcept {
        for (std::size_t k = 0; k < std::size_t(n_r_) * ns_; ++k) st_[k] = filt[k];
    }
    void reset() noexcept {
        net_.reset();
        for (std::size_t k = 0; k < std::size_t(n_r_) * ns_; ++k) st_[k] = T(0);
    }

    /// One tick. in: (n_ridges, 4) row-major [v_L, v_R, u_L, u_R]; out: (n_ridges, 3) row-major.
    void step(const T* in, T* out) noexcept {
        features(in, 4, 1, feat_, nf_, 1);
        net_.step(feat_, out);
    }

    /// n ticks: channel i of ridge r at tick t is x[r * sr + i * si + t * st]; outputs
    /// (n_ridges, n) row-major with row stride ld, as JordanMLP::run.
    void run(const T* x, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, std::ptrdiff_t n, T* y_slip,
             T* y_non, T* y_pred, std::ptrdiff_t ld) noexcept {
        constexpr int K = JordanMLP<T>::chunk_ticks();
        for (std::ptrdiff_t t0 = 0; t0 < n; t0 += K) {
            const int m = int(n - t0 < K ? n - t0 : K);
            features_chunk(x + t0 * st, sr, si, st, m);
            net_.run_staged(m, y_slip + t0, y_non + t0, y_pred + t0, ld);
        }
    }

    /// Mean time of one tick (step()) of all ridges over n_iter ticks, ns (best of repeats),
    /// measured in C++; the state is restored afterwards. NaN for more than 64 ridges.
    double time_step_ns(long n_iter, int repeats = 5) noexcept {
        constexpr int cap = 64;
        if (n_r_ > cap || n_iter < 1) return std::numeric_limits<double>::quiet_NaN();
        T in[4 * cap], out[3 * cap], yp[cap], sv[cap * (2 * kMaxTaus + kMaxTaus + 3)];
        get_state(yp, sv);
        for (int k = 0; k < 4 * n_r_; ++k) in[k] = T(1e3) * T((k % 7) - 3);
        double best = std::numeric_limits<double>::infinity();
        volatile T sink = 0;
        for (int rep = 0; rep < repeats; ++rep) {
            const auto t0 = std::chrono::steady_clock::now();
            for (long it = 0; it < n_iter; ++it) step(in, out);
            const auto t1 = std::chrono::steady_clock::now();
            sink = sink + out[0];
            const double ns = std::chrono::duration<double, std::nano>(t1 - t0).count() / double(n_iter);
            if (ns < best) best = ns;
        }
        set_state(yp, sv);
        return best;
    }

private:
    static int checked_features(int n_lp, int n_abs) {
        if (n_lp < 1 || n_lp > kMaxTaus) throw std::invalid_argument("lp_taus must hold 1 to 8 time constants");
        if (n_abs < 0 || n_abs > kMaxTaus) throw std::invalid_argument("abs_taus must hold 0 to 8 time constants");
        return feature_count(n_lp, n_abs);
    }

    // One tick of features: raw channel i of ridge r at in[r * sr + i * si]; feature j of
    // ridge r written to out[r * orow + j * ocol]. Updates the filter states.
    void features(const T* in, std::ptrdiff_t sr, std::ptrdiff_t si, T* out, std::ptrdiff_t orow,
                  std::ptrdiff_t ocol) noexcept {
        for (int r = 0; r < n_r_; ++r)
            ridge_tick(in + r * sr, si, st_ + std::size_t(r) * ns_, out + r * orow, ocol);
    }

    // One tick of one ridge: raw channel i at x[i * si]; updates its filter states z and
    // writes the ridge's features to o[j * ocol]. The one definition of the bank's
    // recurrences (detector.bank, the specification).
    __attribute__((always_inline)) inline void ridge_tick(const T* x, std::ptrdiff_t si, T* __restrict z,
                                                          T* __restrict o, std::ptrdiff_t ocol) const noexcept {
        const T vl = x[0], vr = x[si], ul = x[2 * si], ur = x[3 * si];
        const T d = vl - vr, s = vl + vr, ad = std::fabs(d);
        o[0] = vl;
        o[ocol] = vr;
        o[2 * ocol] = ul;
        o[3 * ocol] = ur;
        int j = 0;
        for (int k = 0; k < n_lp_; ++k, j += 2) {
            z[j] = a_lp_[k] * z[j] + g_lp_[k] * d;
            z[j + 1] = a_lp_[k] * z[j + 1] + g_lp_[k] * s;
        }
        for (int k = 0; k < n_abs_; ++k, ++j) z[j] = a_abs_[k] * z[j] + g_abs_[k] * ad;
        z[j] = b_ * z[j] + d * inv_fs_;
        z[j + 1] = b_ * z[j + 1] + s * inv_fs_;
        const T held = c_ * z[j + 2], now = std::fabs(z[j]);
        z[j + 2] = now > held ? now : held;
        for (int k = 0; k < ns_; ++k) o[(4 + k) * ocol] = z[k];
    }

    // m <= K ticks of features into the net's staging rows, (n_ridges, nf, K): ridge by ridge, so
    // that a ridge's states stay in registers and every feature row is written in order
    // (the tick-by-tick order of features() wrote 17 rows per tick; measured 1.3x slower
    // per block tick in float64). The same arithmetic as features() (ridge_tick).
    void features_chunk(const T* x0, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, int m) noexcept {
        constexpr int K = JordanMLP<T>::chunk_ticks();
        T z[2 * kMaxTaus + kMaxTaus + 3];
        T* out = net_.staging();
        for (int r = 0; r < n_r_; ++r) {
            T* zs = st_ + std::size_t(r) * ns_;
            for (int k = 0; k < ns_; ++k) z[k] = zs[k];
            T* o = out + std::size_t(r) * nf_ * K;
            const T* xr = x0 + r * sr;
            for (int t = 0; t < m; ++t) ridge_tick(xr + t * st, si, z, o + t, K);
            for (int k = 0; k < ns_; ++k) zs[k] = z[k];
        }
    }

    JordanMLP<T> net_;
    int n_r_, n_lp_, n_abs_, nf_, ns_;
    T a_lp_[kMaxTaus] = {}, g_lp_[kMaxTaus] = {}, a_abs_[kMaxTaus] = {}, g_abs_[kMaxTaus] = {};
    T b_ = 0, c_ = 0, inv_fs_ = 0;
    std::unique_ptr<void, detail::AlignedFree> buf_;
    T* st_ = nullptr;
    T* feat_ = nullptr;
};

}  // namespace detector
}  // namespace tactile
