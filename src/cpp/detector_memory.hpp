// detector_memory.hpp - the load-memory slip detector: a feature stage in front of
// the Jordan MLP kernel (jordan_mlp.hpp).
//
// The paper's net reads [v_L, v_R, u_L, u_R] per ridge and remembers only its own
// y_pred. This stage adds what a creeping slip needs (python:
// tactile_mirror.detector.memory, the specification), per ridge r and tick t:
//
//     load_r  = a load_r  + (v_L - v_R) / fs      shear load, Pa (leaky integral)
//     press_r = a press_r + (v_L + v_R) / fs      normal load, Pa
//     pad_rate = mean_r (v_L - v_R)               the pad's shear rate, Pa/s
//     pad_load = mean_r load_r                    the pad's shear load, Pa
//
// with a = exp(-1 / (fs tau)), and runs the Jordan net on the 8 channels
// [v_L, v_R, u_L, u_R, load, press, pad_rate, pad_load]. The pad channels couple
// the ridges, so all ridges of one pad must be one instance of this class.
//
// RTNeural-like: sizes fixed at construction (which may throw); step(), run(),
// the state accessors allocate nothing and throw nothing. Block runs go in chunks
// of kChunk ticks: the features of a chunk are written time-contiguous into a
// buffer and the net's block path runs over them, so step() and run() give the
// same outputs to round-off of the (identical) feature arithmetic. The
// instances of the net are the ridges: the net's SIMD layout (hidden units in
// lanes, ridges in groups) is unchanged.
#pragma once

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
class MemoryJordan {
public:
    static constexpr int n_raw = 4;       // v_L, v_R, u_L, u_R
    static constexpr int n_features = 8;  // + load, press, pad_rate, pad_load
    static constexpr int n_outputs = 3;

    /// Weights as JordanMLP with n_inputs = 8 (w1: (n_hidden, 9)); fs (Hz) and tau (s)
    /// set the leak of the load integrals.
    MemoryJordan(int n_hidden, int n_ridges, const double* w1, const double* b1, const double* w2,
                 const double* b2, const double* input_mean, const double* input_gain, double fs, double tau,
                 Activation activation = Activation::exact)
        : net_(n_features, n_hidden, n_ridges, w1, b1, w2, b2, input_mean, input_gain, activation),
          n_r_(n_ridges) {
        if (!(std::isfinite(fs) && fs > 0)) throw std::invalid_argument("fs must be a positive number of Hz");
        if (!(std::isfinite(tau) && tau > 0)) throw std::invalid_argument("tau must be a positive number of s");
        a_ = static_cast<T>(std::exp(-1.0 / (fs * tau)));
        inv_fs_ = static_cast<T>(1.0 / fs);
        inv_n_ = static_cast<T>(1.0 / n_ridges);
        const std::size_t count = 2 * std::size_t(n_r_) + std::size_t(n_r_) * n_features * (kChunk + 1) + 16;
        void* mem = std::aligned_alloc(64, ((count * sizeof(T) + 63) / 64) * 64);
        if (!mem) throw std::bad_alloc();
        buf_.reset(mem);
        std::memset(mem, 0, count * sizeof(T));
        T* p = static_cast<T*>(mem);
        load_ = p;
        p += 2 * std::size_t(n_r_);
        feat_ = p;
        p += std::size_t(n_r_) * n_features;
        xch_ = p;
    }

    int n_hidden() const noexcept { return net_.n_hidden(); }
    /// Stage states per ridge: [load, press].
    int n_state() const noexcept { return 2; }
    int n_ridges() const noexcept { return n_r_; }
    T leak() const noexcept { return a_; }
    JordanMLP<T>& net() noexcept { return net_; }
    const JordanMLP<T>& net() const noexcept { return net_; }

    /// State: y_pred(t-1) per ridge (n_ridges) and [load, press] per ridge (2 n_ridges).
    void get_state(T* y_pred, T* load) const noexcept {
        net_.get_state(y_pred);
        for (int k = 0; k < 2 * n_r_; ++k) load[k] = load_[k];
    }
    void set_state(const T* y_pred, const T* load) noexcept {
        net_.set_state(y_pred);
        for (int k = 0; k < 2 * n_r_; ++k) load_[k] = load[k];
    }
    void reset() noexcept {
        net_.reset();
        for (int k = 0; k < 2 * n_r_; ++k) load_[k] = T(0);
    }

    /// One tick. in: (n_ridges, 4) row-major [v_L, v_R, u_L, u_R]; out: (n_ridges, 3) row-major.
    void step(const T* in, T* out) noexcept {
        features(in, 4, 1, feat_, n_features, 1);
        net_.step(feat_, out);
    }

    /// n ticks: feature i of ridge r at tick t is x[r * sr + i * si + t * st]; outputs
    /// (n_ridges, n) row-major with row stride ld, as JordanMLP::run.
    void run(const T* x, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, std::ptrdiff_t n, T* y_slip,
             T* y_non, T* y_pred, std::ptrdiff_t ld) noexcept {
        for (std::ptrdiff_t t0 = 0; t0 < n; t0 += kChunk) {
            const int m = int(n - t0 < kChunk ? n - t0 : kChunk);
            for (int k = 0; k < m; ++k)
                features(x + (t0 + k) * st, sr, si, xch_ + k, std::ptrdiff_t(n_features) * kChunk, kChunk);
            net_.run(xch_, std::ptrdiff_t(n_features) * kChunk, kChunk, 1, m, y_slip + t0, y_non + t0, y_pred + t0,
                     ld);
        }
    }

    /// Mean time of one tick (step()) of all ridges over n_iter ticks, ns (best of repeats),
    /// measured in C++ on the current state, which is restored afterwards.
    double time_step_ns(long n_iter, int repeats = 5) noexcept {
        constexpr int cap = 256;
        if (n_r_ > cap / 4 || n_iter < 1) return std::numeric_limits<double>::quiet_NaN();
        T in[cap], out[3 * cap / 4], yp[cap / 4], ld[cap / 2];
        get_state(yp, ld);
        for (int k = 0; k < 4 * n_r_; ++k) in[k] = T(1e3) * T((k % 7) - 3);
        const double best = best_time_ns(n_iter, repeats, [&](long) { step(in, out); });
        set_state(yp, ld);
        return best;
    }

private:
    // One tick of features: raw channel i of ridge r at in[r * sr + i * si]; feature j of
    // ridge r written to out[r * orow + j * ocol]. Updates the load state.
    void features(const T* in, std::ptrdiff_t sr, std::ptrdiff_t si, T* out, std::ptrdiff_t orow,
                  std::ptrdiff_t ocol) noexcept {
        T pad_rate = 0, pad_load = 0;
        for (int r = 0; r < n_r_; ++r) {
            const T* x = in + r * sr;
            const T vl = x[0], vr = x[si], ul = x[2 * si], ur = x[3 * si];
            const T d = vl - vr, s = vl + vr;
            T* ld = load_ + 2 * r;
            ld[0] = a_ * ld[0] + d * inv_fs_;
            ld[1] = a_ * ld[1] + s * inv_fs_;
            T* o = out + r * orow;
            o[0] = vl;
            o[ocol] = vr;
            o[2 * ocol] = ul;
            o[3 * ocol] = ur;
            o[4 * ocol] = ld[0];
            o[5 * ocol] = ld[1];
            pad_rate += d;
            pad_load += ld[0];
        }
        pad_rate *= inv_n_;
        pad_load *= inv_n_;
        for (int r = 0; r < n_r_; ++r) {
            T* o = out + r * orow;
            o[6 * ocol] = pad_rate;
            o[7 * ocol] = pad_load;
        }
    }

    static constexpr int kChunk = 64;
    JordanMLP<T> net_;
    int n_r_;
    T a_ = 0, inv_fs_ = 0, inv_n_ = 0;
    std::unique_ptr<void, detail::AlignedFree> buf_;
    T* load_ = nullptr;
    T* feat_ = nullptr;
    T* xch_ = nullptr;
};

}  // namespace detector
}  // namespace tactile
