// jordan_mlp.hpp - header-only Jordan recurrent MLP (the slip detector kernel).
//
// One hidden sigmoid layer, two sigmoid output units (y_slip, y_pred) and the
// Jordan feedback: the previous y_pred of the same instance is an extra input.
// y_non = 1 - y_slip is written as a third output. For an instance with input
// features x (n_inputs values, raw units) the recurrence is
//
//     xn      = (x - input_mean) * input_gain             (normalisation)
//     a       = W1[:, :n_in] xn + W1[:, n_in] p + b1      (H pre-activations)
//     h       = sigmoid(a)
//     o       = W2 h + b2                                 (2 pre-activations)
//     y_slip  = sigmoid(o[0]),  y_pred = sigmoid(o[1]),  p <- y_pred
//
// with W1 of shape (H, n_in + 1) row-major and W2 of shape (2, H) row-major.
// Every pre-activation is clamped to [-clamp, clamp] (80 for float, 600 for
// double) before the sigmoid so that no output or state is ever subnormal.
// Subnormal inputs are not flushed here: run the kernel under FTZ/DAZ (the
// Python block call does) if the features can decay into that range.
//
// Design (RTNeural-like): sizes are fixed at construction, where all buffers are
// allocated; step() and run() allocate nothing and throw nothing. N instances
// (one per ridge) share one weight set. The SIMD code is written over the
// library's SIMD layer (simd.hpp: vector types, broadcasts, transposes, lane
// reductions, the sigmoid) and compiled per code variant; the variant is the
// layer's run-time choice (simd::detect_isa) unless set with set_isa(). step()
// and run() go through the same compiled function, so they agree bit for bit. No
// pybind11 or Python in this header.
//
// Layout: the hidden units sit in the SIMD lanes (W1 columns, b1 and W2 rows are
// stored as vectors of consecutive hidden units, H padded with zero weights) and
// the instances go in groups of G <= lanes / 2 whose features and feedback are
// broadcast. Per group and tick the 2G output sums are reduced across lanes into
// one vector [o_slip(r0), o_pred(r0), o_slip(r1), ...] and one vector sigmoid
// gives all the group's outputs. Against instances in lanes this wastes no lane
// on 6 ridges (6 x 16 hidden sigmoids are 12 float or 24 double vectors, not 16
// or 32) at the price of a short transpose-and-add per group. The groups of a
// tick are independent; the ticks are software-pipelined across them (see
// tick_pipelined). For the fast activation a second copy of the weights is
// scaled by -log2(e), so that the pre-activations come out as y = -a log2(e),
// the argument of 2^y, without a multiply per sigmoid; the clamp is then
// +-clamp * log2(e) on y. Measured, 6 ridges x H = 16, one tick (step()) on an
// AVX2 machine (Zen 3): about 0.7x the time of the previous instances-in-lanes
// kernel in float, 0.6x in double.
//
// Block runs (run() over many ticks, 8, 17 or 34 inputs, two or more groups): the input
// part of the hidden pre-activations, b1 + W1[:, :n_in] xn, does not depend on the
// feedback, so a chunk's projections are computed first (project(): eight
// accumulators share each weight load, where the tick loads a weight and a broadcast
// per FMA) and the ticks add only the feedback term, in the same order: the same
// bits as step(). Measured on the filter-bank net, 6 ridges (AMD EPYC, AVX2): 1.27x
// per block tick in double, 1.23x in float.
//
// Activations: Activation (simd::Accuracy) exact or fast, the layer's sigmoid
// approximations, with their measured errors in simd.hpp; the scalar step_one
// uses std::exp for exact.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "simd.hpp"

namespace tactile {
namespace detector {

// The sigmoid's accuracy (see simd.hpp): exact (a few ulp) or fast.
using Activation = simd::Accuracy;

namespace detail {

struct AlignedFree {
    void operator()(void* p) const noexcept { std::free(p); }
};

}  // namespace detail

/// Jordan recurrent MLP with N instances sharing one weight set.
///
/// All sizes are fixed at construction (which may throw std::invalid_argument or
/// std::bad_alloc); every other member is noexcept and allocation-free.
template <typename T>
class JordanMLP {
    static_assert(std::is_same<T, float>::value || std::is_same<T, double>::value,
                  "JordanMLP supports float and double");
    static constexpr int L = 32 / int(sizeof(T));  // lanes of the widest path: the hidden-unit padding

public:
    static constexpr int n_outputs = 3;  // y_slip, y_non, y_pred

    /// w1: (n_hidden, n_inputs + 1) row-major, last column = weight of y_pred(t-1);
    /// b1: (n_hidden); w2: (2, n_hidden) row-major (row 0 y_slip, row 1 y_pred); b2: (2);
    /// input_mean, input_gain: (n_inputs), xn = (x - mean) * gain.
    JordanMLP(int n_inputs, int n_hidden, int n_instances, const double* w1, const double* b1,
              const double* w2, const double* b2, const double* input_mean, const double* input_gain,
              Activation activation = Activation::exact)
        : n_in_(n_inputs), n_h_(n_hidden), n_inst_(n_instances), act_(activation) {
        if (n_inputs < 1 || n_inputs > 64) throw std::invalid_argument("n_inputs must be in [1, 64]");
        if (n_hidden < 1 || n_hidden > 1024) throw std::invalid_argument("n_hidden must be in [1, 1024]");
        if (n_instances < 1 || n_instances > 65536)
            throw std::invalid_argument("n_instances must be in [1, 65536]");
        hp_ = ((n_h_ + L - 1) / L) * L;
        // Instance slots: the last group of a tick may be padded with ghost
        // instances (zero inputs, outputs never read), at most L / 2 - 1 of them.
        const std::size_t n_slot = std::size_t(n_inst_) + L / 2;
        urec_ = ((2 * n_slot + L + L - 1) / L) * L;  // + L: a group's vector store may overhang
        const std::size_t n_w1 = std::size_t(n_h_) * (n_in_ + 1);
        const std::size_t n_w = n_w1 + n_h_ + 2 * std::size_t(n_h_) + 2 + 2 * std::size_t(n_in_);
        // Column-major weights, twice (as given, and times -log2(e) for the fast
        // sigmoid): (n_in + 4) columns of hp_ values [b1, w1[:, 0..n_in-1],
        // w1[:, n_in], w2[0, :], w2[1, :]], zero beyond n_hidden; then b2 as two
        // vectors [b2[k], 0, ...].
        const std::size_t n_col = std::size_t(n_in_ + 4) * hp_ + 2 * L;
        const std::size_t n_slot_pad = ((n_slot + L - 1) / L) * L;
        // State: prev_ (n_slot); scratch: xs_ (one tick's normalised inputs), the
        // chunk buffers of run(): xch_ (n_slot * n_in, kChunk), ych_ (kChunk, urec_).
        const std::size_t n_state = n_slot_pad + n_slot * n_in_ + L + std::size_t(kChunk) * (n_slot * n_in_ + urec_);
        // The block path's input projections (see project()): kChunk ticks of every
        // slot's hp_ pre-activations, for the unrolled sizes and while they fit in
        // 1 MiB (else the block path computes them inside the recurrence, as step()).
        nslot_ = n_slot;
        const std::size_t n_proj = std::size_t(kChunk) * n_slot * hp_;
        const bool proj = hp_ == 16 && (n_in_ == 8 || n_in_ == 17 || n_in_ == 34) && n_proj * sizeof(T) <= (std::size_t(1) << 20);
        const std::size_t n_shb = std::size_t(kChunk) * hp_;
        const std::size_t count = 2 * n_col + n_w + n_state + (proj ? n_proj + n_shb : 0) + 64;
        void* mem = std::aligned_alloc(64, ((count * sizeof(T) + 63) / 64) * 64);
        if (!mem) throw std::bad_alloc();
        buf_.reset(mem);
        T* p = static_cast<T*>(mem);
        std::memset(p, 0, count * sizeof(T));
        wcol_[0] = p;
        p += n_col;
        wcol_[1] = p;
        p += n_col;
        if (proj) {
            pch_ = p;
            p += n_proj;
            shb_ = p;
            p += n_shb;
        }
        ych_ = p;
        p += std::size_t(kChunk) * urec_;
        xch_ = p;
        p += std::size_t(kChunk) * n_slot * n_in_;
        prev_ = p;
        p += n_slot_pad;
        xs_ = p;
        p += n_slot * n_in_ + L;
        w1_ = p;
        p += n_w1;
        b1_ = p;
        p += n_h_;
        w2_ = p;
        p += 2 * std::size_t(n_h_);
        b2_ = p;
        p += 2;
        mean_ = p;
        p += n_in_;
        gain_ = p;
        for (std::size_t k = 0; k < n_w1; ++k) w1_[k] = static_cast<T>(w1[k]);
        for (int k = 0; k < n_h_; ++k) b1_[k] = static_cast<T>(b1[k]);
        for (int k = 0; k < 2 * n_h_; ++k) w2_[k] = static_cast<T>(w2[k]);
        for (int k = 0; k < 2; ++k) b2_[k] = static_cast<T>(b2[k]);
        for (int k = 0; k < n_in_; ++k) {
            mean_[k] = static_cast<T>(input_mean[k]);
            gain_[k] = static_cast<T>(input_gain[k]);
        }
        for (int s = 0; s < 2; ++s) {
            // The scale is applied to the double weights before rounding to T.
            const double f = s == 0 ? 1.0 : -1.4426950408889634;
            T* w = wcol_[s];
            for (int j = 0; j < n_h_; ++j) {
                w[j] = static_cast<T>(f * b1[j]);
                for (int i = 0; i <= n_in_; ++i)
                    w[std::size_t(1 + i) * hp_ + j] = static_cast<T>(f * w1[std::size_t(j) * (n_in_ + 1) + i]);
                w[std::size_t(n_in_ + 2) * hp_ + j] = static_cast<T>(f * w2[j]);
                w[std::size_t(n_in_ + 3) * hp_ + j] = static_cast<T>(f * w2[n_h_ + j]);
            }
            T* b2v = w + std::size_t(n_in_ + 4) * hp_;
            b2v[0] = static_cast<T>(f * b2[0]);
            b2v[L] = static_cast<T>(f * b2[1]);
        }
        isa_ = simd::detect_isa();
    }

    JordanMLP(const JordanMLP&) = delete;
    JordanMLP& operator=(const JordanMLP&) = delete;
    JordanMLP(JordanMLP&&) noexcept = default;
    JordanMLP& operator=(JordanMLP&&) noexcept = default;

    int n_inputs() const noexcept { return n_in_; }
    int n_hidden() const noexcept { return n_h_; }
    int n_instances() const noexcept { return n_inst_; }
    Activation activation() const noexcept { return act_; }
    void set_activation(Activation a) noexcept { act_ = a; }
    /// The code variant run() and step() use (simd::detect_isa() unless set).
    simd::Isa isa() const noexcept { return isa_; }
    /// Select a code variant; returns false (and changes nothing) if it cannot run here.
    bool set_isa(simd::Isa isa) noexcept {
        if (!simd::isa_supported(isa)) return false;
        isa_ = isa;
        return true;
    }

    /// Declare that the last n inputs hold the same value for every instance at each tick
    /// (a pad's mean, detector_bank.hpp): their share of the hidden pre-activations is then
    /// computed once per tick, not per instance (the unrolled 34-input net with n = 17;
    /// other sizes, a 34-input net that shares nothing and the TM_LEAN_UNROLL builds run
    /// the generic path). The sums change order (b1, the shared inputs, then each
    /// instance's own): round-off only; step() and run() still agree bit for bit.
    /// Returns false (and changes nothing) for n outside [0, n_inputs]. Not real-time.
    bool set_shared_inputs(int n) noexcept {
        if (n < 0 || n > n_in_) return false;
        n_shared_ = n;
        return true;
    }
    int shared_inputs() const noexcept { return n_shared_; }

    /// Recurrent state: y_pred(t-1) of every instance (n_instances values).
    void get_state(T* out) const noexcept {
        for (int r = 0; r < n_inst_; ++r) out[r] = prev_[r];
    }
    void set_state(const T* in) noexcept {
        for (int r = 0; r < n_inst_; ++r) prev_[r] = in[r];
    }
    void reset() noexcept {
        for (int r = 0; r < n_inst_; ++r) prev_[r] = T(0);
    }

    /// One tick of all instances. in: (n_instances, n_inputs) row-major raw features;
    /// out: (n_instances, 3) row-major [y_slip, y_non, y_pred].
    void step(const T* in, T* out) noexcept { run(in, n_in_, 1, 0, 1, out, out + 1, out + 2, 3); }

    /// The instance stride of step_feature_major()'s rows: n_instances plus room for the
    /// ghost instances a tick's groups may read (lanes / 2), in whole vectors of the
    /// widest path (32 bytes).
    std::ptrdiff_t feature_major_stride() const noexcept {
        return std::ptrdiff_t(((std::size_t(n_inst_) + L / 2 + L - 1) / L) * L);
    }

    /// One tick from raw features stored feature-major in the caller's buffer, which is
    /// normalised in place: feature i of instance r at x[i * feature_major_stride() + r]
    /// (n_inputs rows). Only the SIMD vectors holding instances are normalised, so the
    /// caller rewrites those before every call (normalising twice changes them); the
    /// instances from n_instances on are ghosts a tick's groups may read: any finite
    /// values. out: (n_instances, 3) as step(); the same bits as step() on the same
    /// features. For a front end that computes its features a vector of instances at a
    /// time (detector_bank.hpp): the normalisation then goes a vector at a time too.
    void step_feature_major(T* x, T* out) noexcept {
        Io io{x, 1, feature_major_stride(), 0, 1, out, out + 1, out + 2, 3};
        io.in_place = true;
        dispatch(io);
    }

    /// One tick of one instance (scalar code). in: n_inputs values; out: 3 values.
    void step_one(int instance, const T* in, T* out) noexcept {
        const int r = instance;
        T xn[64];
        for (int i = 0; i < n_in_; ++i) xn[i] = (in[i] - mean_[i]) * gain_[i];
        const T p = prev_[r];
        T o0 = b2_[0], o1 = b2_[1];
        for (int j = 0; j < n_h_; ++j) {
            const T* w = w1_ + std::size_t(j) * (n_in_ + 1);
            T a = b1_[j];
            for (int i = 0; i < n_in_; ++i) a += w[i] * xn[i];
            a += w[n_in_] * p;
            const T h = sig_scalar(a);
            o0 += w2_[j] * h;
            o1 += w2_[n_h_ + j] * h;
        }
        const T ys = sig_scalar(o0), yp = sig_scalar(o1);
        prev_[r] = yp;
        out[0] = ys;
        out[1] = T(1) - ys;
        out[2] = yp;
    }

    /// Run n ticks. x[r * sr + i * si + t * st] is feature i of instance r at tick t
    /// (strides in elements); outputs y_slip, y_non, y_pred are (n_instances, n)
    /// row-major with row stride ld (>= n).
    void run(const T* x, std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st, std::ptrdiff_t n,
             T* y_slip, T* y_non, T* y_pred, std::ptrdiff_t ld) noexcept {
        dispatch(Io{x, sr, si, st, n, y_slip, y_non, y_pred, ld});
    }

    /// For a front end that computes the features itself (detector_bank.hpp): it
    /// writes up to chunk_ticks() ticks of raw features into staging(): feature i of
    /// instance r at tick k at staging()[(r * n_inputs + i) * chunk_ticks() + k];
    /// run_staged(m, ...) then runs those m ticks as run() would (the same bits),
    /// normalising them in place instead of copying them.
    static constexpr int chunk_ticks() noexcept { return kChunk; }
    T* staging() noexcept { return xch_; }
    void run_staged(int m, T* y_slip, T* y_non, T* y_pred, std::ptrdiff_t ld) noexcept {
        if (m < 1) return;
        if (m > kChunk) m = kChunk;
        run(xch_, std::ptrdiff_t(n_in_) * kChunk, kChunk, 1, m, y_slip, y_non, y_pred, ld);
    }

    /// Mean time of one tick of all instances over n_iter ticks, in ns (best of
    /// `repeats` runs), measured inside C++ on the current state; the state is
    /// restored afterwards. scalar = false times step() (the SIMD path);
    /// scalar = true times step_one() per instance (a plain scalar loop, the
    /// reference). Needs n_instances * n_inputs <= 1024.
    double time_step_ns(long n_iter, int repeats = 5, bool scalar = false) noexcept {
        constexpr int cap = 64 * 16;
        if (n_inst_ * n_in_ > cap || n_iter < 1) return std::numeric_limits<double>::quiet_NaN();
        T in[cap];
        T out[3 * cap];
        T saved[cap];
        get_state(saved);
        for (int k = 0; k < n_inst_ * n_in_; ++k) in[k] = mean_[k % n_in_] + T(0.25) * T((k % 7) - 3);
        // (ticks chained through the state)
        const double best = scalar ? best_time_ns(n_iter, repeats, [&](long) {
            for (int r = 0; r < n_inst_; ++r) step_one(r, in + r * n_in_, out + 3 * r);
        }) : best_time_ns(n_iter, repeats, [&](long) { step(in, out); });
        set_state(saved);
        return best;
    }

private:
    struct Io {
        const T* x;
        std::ptrdiff_t sr, si, st, n;
        T *ys, *yn, *yp;
        std::ptrdiff_t ld;
        bool in_place = false;  // one feature-major tick, normalised in x itself (step_feature_major)
    };

    // The compiled variant for the code path and activation in use.
    void dispatch(const Io& io) noexcept {
#if TM_HAVE_DISPATCH
        if (isa_ == simd::Isa::avx2_fma) {
            if (act_ == Activation::exact)
                run_avx2_exact(io);
            else
                run_avx2_fast(io);
            return;
        }
#endif
        if (act_ == Activation::exact)
            run_base_exact(io);
        else
            run_base_fast(io);
    }

    T sig_scalar(T a) const noexcept {
        return act_ == Activation::exact ? simd::sigmoid_exact_scalar<T>(a) : simd::sigmoid_fast_scalar<T>(a);
    }

    // Largest group of instances per tick (see the header's layout notes): half the
    // lanes, but a quarter in float for the nets with 8 or more inputs. Smaller groups
    // are more independent chains per tick for the out-of-order core, at the price of
    // emptier output vectors; measured with the filter-bank net (17 inputs, 6 ridges,
    // float): block tick 143-147 -> 127-131 ns, step 237-242 -> 231-234 ns, while the
    // paper's net (4 inputs) was 5 % slower per step with them and double gained nothing.
    template <int NL, int NIN>
    static constexpr int group_max() noexcept {
        return (sizeof(T) == 4 && NIN >= 8 && NL >= 8) ? NL / 4 : (NL / 2 > 0 ? NL / 2 : 1);
    }

    // One entry point per code path and activation, so that step() and run()
    // execute the same machine code and agree bit for bit.
#if TM_HAVE_DISPATCH
    TM_TARGET_AVX2 __attribute__((noinline)) void run_avx2_exact(const Io& io) noexcept {
        run_dispatch<32, Activation::exact>(io);
    }
    TM_TARGET_AVX2 __attribute__((noinline)) void run_avx2_fast(const Io& io) noexcept {
        run_dispatch<32, Activation::fast>(io);
    }
#endif
    __attribute__((noinline)) void run_base_exact(const Io& io) noexcept {
        run_dispatch<simd::kBaseBytes, Activation::exact>(io);
    }
    __attribute__((noinline)) void run_base_fast(const Io& io) noexcept {
        run_dispatch<simd::kBaseBytes, Activation::fast>(io);
    }

    // The paper's network (4 inputs, 16 hidden units), the load-memory net (8
    // inputs, detector_memory.hpp) and the default filter-bank net (17 inputs,
    // detector_bank.hpp; 34 with the pad's mean) are unrolled at compile time: the generic path (sizes at
    // run time) took 2.5x as long per tick for the bank net.
    template <int B, Activation A>
    __attribute__((always_inline)) inline void run_dispatch(const Io& io) noexcept {
        constexpr int NL = simd::Vec<T, B>::lanes;
        if (n_in_ == 4 && hp_ == 16)
            run_impl<B, A, 4, 0, 16 / NL>(io);
        else if (n_in_ == 8 && hp_ == 16)
            run_impl<B, A, 8, 0, 16 / NL>(io);
        else if (n_in_ == 17 && hp_ == 16)
            run_impl<B, A, 17, 0, 16 / NL>(io);
#ifndef TM_LEAN_UNROLL
        // (the sanitizer builds leave this size to the generic path: each unrolled size
        // adds minutes to their compile)
        else if (n_in_ == 34 && hp_ == 16 && n_shared_ == 17)
            run_impl<B, A, 34, 17, 16 / NL>(io);
#endif
        else
            run_impl<B, A, 0, 0, 0>(io);  // (shares nothing: the same sums, another order)
    }

    template <int B, Activation A, int NIN, int NS, int NV>
    __attribute__((always_inline)) inline void run_impl(const Io& io) noexcept {
        const int nin = NIN > 0 ? NIN : n_in_;
        if (io.n == 1 && (io.in_place || (io.si == 1 && io.sr == nin))) {
            const int ni = n_inst_;
            T* __restrict xs = xs_;
            const T* tin = xs_;  // the tick's normalised features, instance r feature i at tin[r * xr + i * xi]
            std::ptrdiff_t xr = nin, xi = 1;
            if (io.in_place) {
                // One feature-major tick (step_feature_major): normalised where it is,
                // a vector of instances at a time.
                typedef typename simd::Vec<T, B>::type V;
                constexpr int NL = simd::Vec<T, B>::lanes;
                T* x = const_cast<T*>(io.x);
                tin = x;
                xr = 1;
                xi = io.si;
                // Only the vectors holding instances (their ghost lanes too): the vectors
                // past them keep the finite values the caller left there, and the groups
                // never read them.
                const T* __restrict mu = mean_;
                const T* __restrict g = gain_;
                const std::ptrdiff_t nl = ((n_inst_ + NL - 1) / NL) * NL;
                if (nl == NL) {
                    // one vector of instances per row: no inner loop (measured, 6 ridges in
                    // float: the pad net's step 288 -> 262 ns, the bank net's 166 -> 159)
                    _Pragma("GCC unroll 64") for (int i = 0; i < nin; ++i) {
                        T* row = x + i * xi;
                        simd::store(row, (simd::load<V>(row) - mu[i]) * g[i]);
                    }
                } else {
                    for (int i = 0; i < nin; ++i) {
                        T* row = x + i * xi;
                        const T mi = mu[i], gi = g[i];
                        for (std::ptrdiff_t r = 0; r < nl; r += NL) simd::store(row + r, (simd::load<V>(row + r) - mi) * gi);
                    }
                }
            } else if (NIN == 4) {
                // One tick of contiguous features (step()): normalise into xs_,
                // one 4-lane vector per instance.
                const T* __restrict xin = io.x;
                typedef typename simd::Vec<T, 4 * sizeof(T)>::type V4;
                V4 mu, g;
                std::memcpy(&mu, mean_, sizeof mu);
                std::memcpy(&g, gain_, sizeof g);
                for (int r = 0; r < ni; ++r) {
                    V4 v;
                    std::memcpy(&v, xin + 4 * r, sizeof v);
                    v = (v - mu) * g;
                    std::memcpy(xs + 4 * r, &v, sizeof v);
                }
            } else {
                const T* __restrict xin = io.x;
                const T* __restrict mu = mean_;
                const T* __restrict g = gain_;
                for (int r = 0; r < ni; ++r)
                    for (int i = 0; i < nin; ++i) xs[r * nin + i] = (xin[r * nin + i] - mu[i]) * g[i];
            }
            tick_impl<B, A, NIN, NS, NV>(tin, xr, xi, 0, 1, ych_);
            const T* __restrict u = ych_;
            T* __restrict pv = prev_;
            T* __restrict ys = io.ys;
            T* __restrict yn = io.yn;
            T* __restrict yp = io.yp;
            const std::ptrdiff_t ld = io.ld;
            for (int r = 0; r < ni; ++r) {
                const T a = u[2 * r], b = u[2 * r + 1];
                ys[r * ld] = a;
                yn[r * ld] = T(1) - a;
                yp[r * ld] = b;
                pv[r] = b;
            }
            return;
        }
        // Chunks of kChunk ticks: normalise the chunk's inputs into xch_ with time
        // contiguous (reading each input row sequentially), run the ticks, then
        // write the outputs row by row. Both passes go lanes ticks at a time (a
        // transpose for the outputs) and prefetch the rows' next chunk; with 6
        // instances they are still about a fifth of the block time (memory traffic
        // of 42 rows), less than when interleaved with the ticks (measured).
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr int GM = group_max<NL, NIN>();
        constexpr int CL = 64 / int(sizeof(T));  // values per cache line
        const int ni = n_inst_;
        const int ng = (ni + GM - 1) / GM;
        const int gsz = (ni + ng - 1) / ng;  // group size, as in tick_impl
        const std::ptrdiff_t ld = io.ld;
        for (std::ptrdiff_t t0 = 0; t0 < io.n; t0 += kChunk) {
            const int m = int(io.n - t0 < kChunk ? io.n - t0 : kChunk);
            const bool more = t0 + 2 * kChunk <= io.n;
            // (src is dst for the staged features of run_staged(): normalised in place)
            for (int r = 0; r < ni; ++r)
                for (int i = 0; i < nin; ++i) {
                    const T* src = io.x + r * io.sr + i * io.si + t0 * io.st;
                    T* dst = xch_ + std::size_t(r * nin + i) * kChunk;
                    const T mu = mean_[i], g = gain_[i];
                    int k = 0;
                    if (io.st == 1) {
                        if (more)
                            for (int c = 0; c < kChunk; c += CL) __builtin_prefetch(src + kChunk + c, 0, 3);
                        for (; k + NL <= m; k += NL) {
                            V v = simd::load<V>(src + k);
                            v = (v - mu) * g;
                            std::memcpy(dst + k, &v, sizeof v);
                        }
                    }
                    for (; k < m; ++k) dst[k] = (src[k * io.st] - mu) * g;
                }
            const bool projected = NV > 0 && NIN > 0 && pch_ && ng > 1;
            tick_impl<B, A, NIN, NS, NV>(xch_, std::ptrdiff_t(nin) * kChunk, kChunk, 1, m, ych_, projected);
            for (int r0 = 0; r0 < ni; r0 += gsz) {
                const int gr = ni - r0 < gsz ? ni - r0 : gsz;  // real instances of the group
                T* ys = io.ys + r0 * ld + t0;
                T* yn = io.yn + r0 * ld + t0;
                T* yp = io.yp + r0 * ld + t0;
                const T* u = ych_ + 2 * r0;
                if (more)
                    for (int j = 0; j < gr; ++j)
                        for (int c = 0; c < kChunk; c += CL) {
                            __builtin_prefetch(ys + j * ld + kChunk + c, 1, 3);
                            __builtin_prefetch(yn + j * ld + kChunk + c, 1, 3);
                            __builtin_prefetch(yp + j * ld + kChunk + c, 1, 3);
                        }
                int k = 0;
                for (; k + NL <= m; k += NL) {
                    // NL group vectors [y_slip(0), y_pred(0), y_slip(1), ...] of NL
                    // ticks -> one vector per output holding the NL ticks.
                    V v[NL];
                    _Pragma("GCC unroll 8") for (int q = 0; q < NL; ++q) v[q] = simd::load<V>(u + (k + q) * urec_);
                    simd::transpose(v);
                    // (Stored from register copies: stored straight from v[], GCC
                    // reloaded the halves of v[] from the stack, which stalled.)
                    _Pragma("GCC unroll 4") for (int j = 0; j < GM; ++j) {
                        if (j >= gr) break;
                        const V a = v[2 * j], b = v[2 * j + 1], c = T(1) - a;
                        std::memcpy(ys + j * ld + k, &a, sizeof a);
                        std::memcpy(yn + j * ld + k, &c, sizeof c);
                        std::memcpy(yp + j * ld + k, &b, sizeof b);
                    }
                }
                for (; k < m; ++k)
                    for (int j = 0; j < gr; ++j) {
                        const T a = u[k * urec_ + 2 * j];
                        ys[j * ld + k] = a;
                        yn[j * ld + k] = T(1) - a;
                        yp[j * ld + k] = u[k * urec_ + 2 * j + 1];
                    }
            }
            for (int r = 0; r < ni; ++r) prev_[r] = ych_[std::size_t(m - 1) * urec_ + 2 * r + 1];
        }
    }

    // m ticks: normalised feature i of instance r at tick k is xs[r * xr + i * xi
    // + k * xk]; outputs [y_slip, y_pred] of instance r at u + k * urec_ + 2 r. The
    // feedback of the first tick comes from prev_, of the others from the previous
    // tick's outputs; prev_ itself is not updated here. Instances go in ng groups
    // of G <= lanes / 2 (the last one padded with ghost instances if needed).
    template <int B, Activation A, int NIN, int NS, int NV>
    __attribute__((always_inline)) inline void tick_impl(const T* xs, std::ptrdiff_t xr, std::ptrdiff_t xi,
                                                         std::ptrdiff_t xk, int m, T* u,
                                                         bool projected = false) noexcept {
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr int GM = group_max<NL, NIN>();
        const int ng = (n_inst_ + GM - 1) / GM;
        const int g = (n_inst_ + ng - 1) / ng;
        const Ticks t{xs, xr, xi, xk, m, u, ng, projected};
        // g <= GM <= 4; each size is instantiated once.
        if constexpr (GM >= 4) {
            if (g == 4) return tick_groups<B, A, NIN, NS, NV, 4>(t);
        }
        if constexpr (GM >= 3) {
            if (g == 3) return tick_groups<B, A, NIN, NS, NV, 3>(t);
        }
        if constexpr (GM >= 2) {
            if (g == 2) return tick_groups<B, A, NIN, NS, NV, 2>(t);
        }
        tick_groups<B, A, NIN, NS, NV, 1>(t);
    }

    struct Ticks {
        const T* xs;
        std::ptrdiff_t xr, xi, xk;
        int m;
        T* u;
        int ng;
        bool projected;  // the input projections of the m ticks are in pch_ (project())
    };

    template <int B, Activation A, int NIN, int NS, int NV, int G>
    __attribute__((always_inline)) inline void tick_groups(const Ticks& t) noexcept {
        if constexpr (NV > 0) {
            if (t.ng > 1) {
                if (t.projected)
                    tick_pipelined<B, A, NIN, NS, NV, G, true>(t);
                else
                    tick_pipelined<B, A, NIN, NS, NV, G, false>(t);
                return;
            }
        }
        for (int k = 0; k < t.m; ++k) {
            const T* xk = t.xs + k * t.xk;
            T* uk = t.u + std::size_t(k) * urec_;
            // y_pred of the previous tick: the state, then the previous record.
            const T* pk = k == 0 ? prev_ : uk - urec_ + 1;
            const std::ptrdiff_t ps = k == 0 ? 1 : 2;
            for (int g = 0, r0 = 0; g < t.ng; ++g, r0 += G)
                group<B, A, NIN, NS, NV, G>(xk + r0 * t.xr, t.xr, t.xi, pk + r0 * ps, ps, uk + 2 * r0);
        }
    }

    // Software-pipelined ticks for ng >= 2 groups of G instances (NV known): the
    // output sigmoid of one group is computed right after the hidden sigmoids of
    // the next group (for the last group of a tick, of the first group of the next
    // tick). A group's chain hidden layer -> sums -> output is long and serial, and
    // the out-of-order window does not reach far enough to overlap consecutive
    // groups by itself (measured: groups ran almost one after the other); placing
    // independent work next to it in program order does.
    template <int B, Activation A, int NIN, int NS, int NV, int G, bool PROJ>
    __attribute__((always_inline)) inline void tick_pipelined(const Ticks& t) noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr int KH = NV * G;
        V o{};            // pending output pre-activations
        T* od = nullptr;  // and where their sigmoids go
        // The input projections (PROJ) of all m ticks first, in one pass (measured
        // faster than placing them between the ticks, next to the serial chain).
        if constexpr (PROJ) project<B, A, NIN, NS, NV>(t.m, t.ng * G);
        for (int k = 0; k < t.m; ++k) {
            const T* xk = t.xs + k * t.xk;
            T* uk = t.u + std::size_t(k) * urec_;
            const T* pk = k == 0 ? prev_ : uk - urec_ + 1;
            const std::ptrdiff_t ps = k == 0 ? 1 : 2;
            V c[NV];  // the tick's shared part (NS inputs), once for all groups
            if constexpr (NS > 0 && !PROJ) shared_part<B, A, NIN, NS, NV>(xk, t.xi, c);
            for (int g = 0, r0 = 0; g < t.ng; ++g, r0 += G) {
                V a[KH];
                hidden_pre<B, A, NIN, NS, NV, G, PROJ>(xk + r0 * t.xr, t.xr, t.xi, pk + r0 * ps, ps, a,
                                                   PROJ ? pch_ + (std::size_t(k) * nslot_ + r0) * (NV * NL) : nullptr,
                                                   c);
                sigmoid_batch<B, A, KH>(a);
                if (od) {
                    simd::sigmoid_k<T, B, A, 1, A == Activation::fast>(&o);
                    std::memcpy(od, &o, sizeof(V));
                }
                o = hidden_post<B, A, NV, G>(a);
                od = uk + 2 * r0;
            }
        }
        simd::sigmoid_k<T, B, A, 1, A == Activation::fast>(&o);
        std::memcpy(od, &o, sizeof(V));
    }

    // K sigmoids in interleaved passes of at most 4 vectors: measured as fast as
    // passes of 2 to 9 on the reference machine, with fewer spills.
    template <int B, Activation A, int K>
    static __attribute__((always_inline)) inline void sigmoid_batch(typename simd::Vec<T, B>::type* a) noexcept {
        constexpr int SB = 4;
        constexpr int NP = (K + SB - 1) / SB;           // passes
        constexpr int P0 = K / NP, PX = K % NP;         // balanced sizes: PX passes of P0 + 1
        int off = 0;
        _Pragma("GCC unroll 8") for (int q = 0; q < NP; ++q) {
            if (q < PX) {
                simd::sigmoid_k<T, B, A, P0 + 1, A == Activation::fast>(a + off);
                off += P0 + 1;
            } else {
                simd::sigmoid_k<T, B, A, P0, A == Activation::fast>(a + off);
                off += P0;
            }
        }
    }

    // Pre-activations of the G * NV hidden vectors of a group (a[v * G + j]). PROJ: the
    // input part comes from the group's projections at pr (project()), and only the
    // feedback term is added, the same last FMA as without.
    template <int B, Activation A, int NIN, int NS, int NV, int G, bool PROJ = false>
    __attribute__((always_inline)) inline void hidden_pre(const T* xg, std::ptrdiff_t xr, std::ptrdiff_t xi,
                                                          const T* pg, std::ptrdiff_t ps,
                                                          typename simd::Vec<T, B>::type* a,
                                                          const T* pr = nullptr,
                                                          const typename simd::Vec<T, B>::type* c = nullptr) const noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr std::size_t cs = std::size_t(NV * NL);
        const T* __restrict wc = wcol_[A == Activation::fast ? 1 : 0];
        V pb[G];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) pb[j] = simd::bcast<T, B>(pg + j * ps);
        _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v) {
            const T* w = wc + std::size_t(v) * NL;
            _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                V acc;
                if constexpr (PROJ) {
                    acc = simd::load<V>(pr + j * cs + v * NL);
                } else {
                    acc = NS > 0 ? c[v] : simd::load<V>(w);
                    _Pragma("GCC unroll 8") for (int i = 0; i < NIN - NS; ++i)
                        acc += simd::load<V>(w + (1 + i) * cs) * simd::bcast<T, B>(xg + j * xr + i * xi);
                }
                a[v * G + j] = acc + simd::load<V>(w + (1 + NIN) * cs) * pb[j];
            }
        }
    }

    // The part of the hidden pre-activations that every instance shares at a tick: b1
    // plus the last NS inputs' terms (a pad's mean, the same for every ridge: read off
    // the first instance, xg[i * xi]), summed from b1 in input order; each instance then
    // adds its own NIN - NS inputs (hidden_pre, group, project_ticks: the same order
    // everywhere, so step() and run() agree bit for bit).
    template <int B, Activation A, int NIN, int NS, int NV>
    __attribute__((always_inline)) inline void shared_part(const T* xg, std::ptrdiff_t xi,
                                                           typename simd::Vec<T, B>::type* c) const noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr std::size_t cs = std::size_t(NV * NL);
        const T* __restrict wc = wcol_[A == Activation::fast ? 1 : 0];
        _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v) {
            V acc = simd::load<V>(wc + v * NL);
            _Pragma("GCC unroll 32") for (int i = NIN - NS; i < NIN; ++i)
                acc += simd::load<V>(wc + (1 + i) * cs + v * NL) * simd::bcast<T, B>(xg + i * xi);
            c[v] = acc;
        }
    }

    // The block path's input projections: for the m ticks of the normalised chunk in
    // xch_ (time-contiguous rows, as run_impl writes them) and the first nslots slots,
    // pch_[(k * nslot_ + r) * NV * NL + h] = b1[h] + sum_i W1[h, i] xn_i(r, k), summed
    // in the order of hidden_pre (b1, then i = 0, 1, ...), so that hidden_pre<PROJ>
    // gives the bits of hidden_pre without. They do not depend on the feedback, so they
    // leave the recurrence's serial chain: here KT ticks share each weight load
    // (8 accumulators), where hidden_pre loads a weight and a broadcast per FMA.
    template <int B, Activation A, int NIN, int NS, int NV>
    __attribute__((always_inline)) inline void project(int m, int nslots) noexcept {
        constexpr int KT = NV >= 8 ? 1 : 8 / NV;
        if constexpr (NS > 0) {
            // the shared parts of the m ticks, from the first slot's rows
            typedef typename simd::Vec<T, B>::type V;
            constexpr int NL = simd::Vec<T, B>::lanes;
            for (int k = 0; k < m; ++k) {
                V c[NV];
                shared_part<B, A, NIN, NS, NV>(xch_ + k, kChunk, c);
                std::memcpy(shb_ + std::size_t(k) * NV * NL, c, sizeof c);
            }
        }
        for (int r = 0; r < nslots; ++r) {
            int k = 0;
            for (; k + KT <= m; k += KT) project_ticks<B, A, NIN, NS, NV, KT>(r, k);
            for (; k < m; ++k) project_ticks<B, A, NIN, NS, NV, 1>(r, k);
        }
    }

    // project() for ticks k to k + KT - 1 of slot r.
    template <int B, Activation A, int NIN, int NS, int NV, int KT>
    __attribute__((always_inline)) inline void project_ticks(int r, int k) noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr std::size_t cs = std::size_t(NV * NL);
        const T* __restrict wc = wcol_[A == Activation::fast ? 1 : 0];
        const T* __restrict xr = xch_ + std::size_t(r) * NIN * kChunk + k;
        V acc[NV * KT];
        _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v) {
            const V b = simd::load<V>(wc + v * NL);
            _Pragma("GCC unroll 8") for (int q = 0; q < KT; ++q)
                acc[v * KT + q] = NS > 0 ? simd::load<V>(shb_ + std::size_t(k + q) * cs + v * NL) : b;
        }
        _Pragma("GCC unroll 32") for (int i = 0; i < NIN - NS; ++i) {
            V x[KT];
            _Pragma("GCC unroll 8") for (int q = 0; q < KT; ++q)
                x[q] = simd::bcast<T, B>(xr + std::size_t(i) * kChunk + q);
            _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v) {
                const V w = simd::load<V>(wc + (1 + i) * cs + v * NL);
                _Pragma("GCC unroll 8") for (int q = 0; q < KT; ++q) acc[v * KT + q] += w * x[q];
            }
        }
        _Pragma("GCC unroll 8") for (int q = 0; q < KT; ++q)
            _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v)
                std::memcpy(pch_ + (std::size_t(k + q) * nslot_ + r) * cs + v * NL, &acc[v * KT + q], sizeof(V));
    }

    // Output pre-activations of a group from its hidden activations: one vector
    // [o_slip(0), o_pred(0), o_slip(1), ...].
    template <int B, Activation A, int NV, int G>
    __attribute__((always_inline)) inline typename simd::Vec<T, B>::type hidden_post(
        const typename simd::Vec<T, B>::type* a) const noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr std::size_t cs = std::size_t(NV * NL);
        const int nin = n_in_;
        const T* __restrict wc = wcol_[A == Activation::fast ? 1 : 0];
        const T* b2v = wc + (nin + 4) * cs;
        V s[NL];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
            s[2 * j] = simd::load<V>(b2v);
            s[2 * j + 1] = simd::load<V>(b2v + L);
        }
        _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v) {
            const T* w = wc + std::size_t(v) * NL;
            _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                s[2 * j] += simd::load<V>(w + (2 + nin) * cs) * a[v * G + j];
                s[2 * j + 1] += simd::load<V>(w + (3 + nin) * cs) * a[v * G + j];
            }
        }
        return simd::reduce_lanes<T, B, 2 * G>(s);
    }

    // One tick of G instances: feature i of instance j at xg[j * xr + i * xi],
    // feedback at pg[j * ps]; writes lanes [y_slip(0), y_pred(0), y_slip(1), ...]
    // (one vector) at ug. NIN, NV > 0: number of inputs and of hidden vectors known
    // at compile time; then all G * NV hidden sigmoids of the group go through one
    // interleaved pass (measured faster than a pass per hidden vector, and than one
    // pass over all groups, which spills too much).
    template <int B, Activation A, int NIN, int NS, int NV, int G>
    __attribute__((always_inline)) inline void group(const T* xg, std::ptrdiff_t xr, std::ptrdiff_t xi, const T* pg,
                                                     std::ptrdiff_t ps, T* ug) const noexcept {
        typedef typename simd::Vec<T, B>::type V;
        constexpr int NL = simd::Vec<T, B>::lanes;
        constexpr int KB = NV > 0 ? NV : 1;  // hidden vectors per sigmoid pass
        constexpr bool S = A == Activation::fast;  // pre-activations scaled by -log2(e)
        const int nin = NIN > 0 ? NIN : n_in_;
        const int nv = NV > 0 ? NV : hp_ / NL;
        const std::size_t cs = NV > 0 ? std::size_t(NV * NL) : std::size_t(hp_);  // column stride
        const T* __restrict wc = wcol_[S ? 1 : 0];
        const T* b2v = wc + (nin + 4) * cs;
        V c[NV > 0 ? NV : 1];  // the shared part (NS > 0: NV > 0, KB = NV, one pass)
        if constexpr (NS > 0) shared_part<B, A, NIN, NS, NV>(xg, xi, c);
        V pb[G], s0[G], s1[G];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
            pb[j] = simd::bcast<T, B>(pg + j * ps);
            s0[j] = simd::load<V>(b2v);
            s1[j] = simd::load<V>(b2v + L);
        }
        for (int v0 = 0; v0 < nv; v0 += KB) {
            V a[KB * G];
            _Pragma("GCC unroll 8") for (int v = 0; v < KB; ++v) {
                const T* w = wc + std::size_t(v0 + v) * NL;
                _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                    V acc = NS > 0 ? c[v0 + v] : simd::load<V>(w);
                    _Pragma("GCC unroll 8") for (int i = 0; i < nin - NS; ++i)
                        acc += simd::load<V>(w + (1 + i) * cs) * simd::bcast<T, B>(xg + j * xr + i * xi);
                    a[v * G + j] = acc + simd::load<V>(w + (1 + nin) * cs) * pb[j];
                }
            }
            sigmoid_batch<B, A, KB * G>(a);
            _Pragma("GCC unroll 8") for (int v = 0; v < KB; ++v) {
                const T* w = wc + std::size_t(v0 + v) * NL;
                _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                    s0[j] += simd::load<V>(w + (2 + nin) * cs) * a[v * G + j];
                    s1[j] += simd::load<V>(w + (3 + nin) * cs) * a[v * G + j];
                }
            }
        }
        V s[NL];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
            s[2 * j] = s0[j];
            s[2 * j + 1] = s1[j];
        }
        V o = simd::reduce_lanes<T, B, 2 * G>(s);
        simd::sigmoid_k<T, B, A, 1, S>(&o);
        std::memcpy(ug, &o, sizeof(V));
    }

    int n_in_, n_h_, n_inst_, hp_ = 0;
    std::size_t urec_ = 0, nslot_ = 0;
    Activation act_;
    simd::Isa isa_ = simd::Isa::baseline;
    std::unique_ptr<void, detail::AlignedFree> buf_;
    static constexpr int kChunk = 64;
    T* wcol_[2] = {nullptr, nullptr};
    T* xs_ = nullptr;
    T* xch_ = nullptr;
    T* ych_ = nullptr;
    T* pch_ = nullptr;  // input projections of the block path (nullptr: not used)
    T* shb_ = nullptr;  // the shared parts of a chunk's ticks (set_shared_inputs), kChunk x hp_
    int n_shared_ = 0;
    T* prev_ = nullptr;
    T* w1_ = nullptr;
    T* b1_ = nullptr;
    T* w2_ = nullptr;
    T* b2_ = nullptr;
    T* mean_ = nullptr;
    T* gain_ = nullptr;
};

}  // namespace detector
}  // namespace tactile
