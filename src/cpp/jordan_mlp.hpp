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
// (one per ridge) share one weight set; the instances sit in SIMD lanes
// (structure of arrays, 8 float or 4 double lanes per 256-bit vector). The SIMD
// code is written with GCC vector extensions and compiled twice: for the
// baseline ISA and for AVX2+FMA; the AVX2 path is selected at construction with
// __builtin_cpu_supports. No pybind11 or Python in this header.
//
// Activations: Activation::exact is accurate to a few ulp (vectorised exp with
// Cody-Waite range reduction and a degree-13/7 Taylor polynomial, then a true
// division; the scalar step_one uses std::exp); Activation::fast uses 2^x = 2^n * P6(f), |f| <= 1/2
// (relative error below 1.9e-9) and, for float on x86, a reciprocal estimate
// with one Newton step; it is vectorised in both paths. Measured over 2e6
// points in [-100, 100] against scipy.special.expit: |error| <= 4.7e-10 in
// double, <= 1.9e-7 in float (exact float: 8.9e-8).
#pragma once

#include <chrono>
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

#if (defined(__x86_64__) || defined(__i386__)) && (defined(__GNUC__) || defined(__clang__))
#define TM_DETECTOR_X86 1
#include <immintrin.h>
#endif

// Vector types are passed between always-inline helpers only; the ABI note about
// 32-byte vector arguments does not apply.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wpsabi"

namespace tm_core {
namespace detector {

enum class Activation : int { exact = 0, fast = 1 };
enum class SimdPath : int { generic = 0, avx2 = 1 };

inline const char* simd_path_name(SimdPath p) { return p == SimdPath::avx2 ? "avx2+fma" : "generic"; }

/// True when this CPU can run the AVX2+FMA path.
inline bool cpu_has_avx2_fma() {
#ifdef TM_DETECTOR_X86
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
#else
    return false;
#endif
}

namespace detail {

template <typename T>
struct Scalar;

template <>
struct Scalar<float> {
    typedef std::int32_t iscalar;
    static constexpr float clamp = 80.0f;
    static constexpr float round_magic = 12582912.0f;  // 1.5 * 2^23
    static constexpr int bias = 127;
    static constexpr int mant = 23;
};

template <>
struct Scalar<double> {
    typedef std::int64_t iscalar;
    static constexpr double clamp = 600.0;
    static constexpr double round_magic = 6755399441055744.0;  // 1.5 * 2^52
    static constexpr std::int64_t bias = 1023;
    static constexpr int mant = 52;
};

// SIMD vector of Bytes bytes (16: SSE2/NEON baseline, 32: AVX2).
template <typename T, int Bytes>
struct Vec;

#define TM_DETECTOR_VEC(T, IT, BYTES)                                       \
    template <>                                                             \
    struct Vec<T, BYTES> : Scalar<T> {                                      \
        typedef T type __attribute__((vector_size(BYTES)));                 \
        typedef IT itype __attribute__((vector_size(BYTES)));               \
        static constexpr int lanes = BYTES / int(sizeof(T));                \
    };
TM_DETECTOR_VEC(float, std::uint32_t, 16)
TM_DETECTOR_VEC(float, std::uint32_t, 32)
TM_DETECTOR_VEC(double, std::uint64_t, 16)
TM_DETECTOR_VEC(double, std::uint64_t, 32)
#undef TM_DETECTOR_VEC

// 2^f on [-1/2, 1/2]: relative error < 1.9e-9 (least squares on Chebyshev nodes).
constexpr double kP0 = 1.0000000005920207;
constexpr double kP1 = 0.69314720560051013;
constexpr double kP2 = 0.24022646608714027;
constexpr double kP3 = 0.055503289975174459;
constexpr double kP4 = 0.0096185195343476276;
constexpr double kP5 = 0.001339986036321298;
constexpr double kP6 = 0.00015337576834253096;

template <typename T>
__attribute__((always_inline)) inline T clampv(T a, T lo, T hi) {
    return a < lo ? lo : (a > hi ? hi : a);
}

// Scalar sigmoids (used by step_one and as the reference inside the kernel).
template <typename T>
inline T sigmoid_exact_scalar(T a) {
    a = clampv<T>(a, -Scalar<T>::clamp, Scalar<T>::clamp);
    return T(1) / (T(1) + std::exp(-a));
}

template <typename T>
inline T sigmoid_fast_scalar(T a) {
    typedef typename std::make_unsigned<typename Scalar<T>::iscalar>::type I;  // modular shifts
    a = clampv<T>(a, -Scalar<T>::clamp, Scalar<T>::clamp);
    const T y = a * T(-1.4426950408889634);
    const T t = y + Scalar<T>::round_magic;  // round to nearest integer (no -ffast-math)
    I tb;
    std::memcpy(&tb, &t, sizeof tb);
    const T f = y - (t - Scalar<T>::round_magic);
    const T f2 = f * f;
    const T p = ((T(kP3) * f + T(kP2)) * f2 + (T(kP1) * f + T(kP0))) +
                (T(kP6) * f2 + (T(kP5) * f + T(kP4))) * (f2 * f2);
    const I eb = static_cast<I>((tb + static_cast<I>(Scalar<T>::bias)) << Scalar<T>::mant);
    T scale;
    std::memcpy(&scale, &eb, sizeof scale);
    return T(1) / (T(1) + p * scale);
}

// 1/d for d >= 1. Exact division by default; for float on x86 the hardware
// reciprocal estimate refined by one Newton step (relative error < 2.5e-7 after
// rounding), which removes the divider from the fast path.
template <typename V>
__attribute__((always_inline)) inline V recip_fast(V d) {
    return 1 / d;
}
#ifdef TM_DETECTOR_X86
__attribute__((always_inline)) inline Vec<float, 16>::type recip_fast(Vec<float, 16>::type d) {
    typedef Vec<float, 16>::type V;
    const V r = (V)_mm_rcp_ps((__m128)d);
    return r + r * (1.0f - d * r);
}
// Only ever inlined into the AVX2 tick: the builtin is expanded there.
__attribute__((always_inline)) inline Vec<float, 32>::type recip_fast(Vec<float, 32>::type d) {
    typedef Vec<float, 32>::type V;
    const V r = (V)__builtin_ia32_rcpps256((__v8sf)d);
    return r + r * (1.0f - d * r);
}
#endif

// Clamp to [-c, c] with min/max instructions (a NaN argument becomes -c).
template <typename V, typename T>
__attribute__((always_inline)) inline V clamp_sym(V a, T c) {
    const V lo = V{} - c, hi = V{} + c;
    a = a > lo ? a : lo;
    return a < hi ? a : hi;
}
#ifdef TM_DETECTOR_X86
__attribute__((always_inline)) inline Vec<float, 16>::type clamp_sym(Vec<float, 16>::type a, float c) {
    typedef Vec<float, 16>::type V;
    return (V)__builtin_ia32_minps(__builtin_ia32_maxps((__v4sf)a, (__v4sf)(V{} - c)), (__v4sf)(V{} + c));
}
__attribute__((always_inline)) inline Vec<double, 16>::type clamp_sym(Vec<double, 16>::type a, double c) {
    typedef Vec<double, 16>::type V;
    return (V)__builtin_ia32_minpd(__builtin_ia32_maxpd((__v2df)a, (__v2df)(V{} - c)), (__v2df)(V{} + c));
}
// The 32-byte versions are only ever inlined into the AVX2 tick.
__attribute__((always_inline)) inline Vec<float, 32>::type clamp_sym(Vec<float, 32>::type a, float c) {
    typedef Vec<float, 32>::type V;
    return (V)__builtin_ia32_minps256(__builtin_ia32_maxps256((__v8sf)a, (__v8sf)(V{} - c)), (__v8sf)(V{} + c));
}
__attribute__((always_inline)) inline Vec<double, 32>::type clamp_sym(Vec<double, 32>::type a, double c) {
    typedef Vec<double, 32>::type V;
    return (V)__builtin_ia32_minpd256(__builtin_ia32_maxpd256((__v4df)a, (__v4df)(V{} - c)),
                                      (__v4df)(V{} + c));
}
#endif

// K independent sigmoids in place, computed stage by stage across the K vectors
// so that their dependency chains interleave in the instruction stream (the
// sigmoid is a long chain; one at a time leaves the FP units idle).
#define TM_K _Pragma("GCC unroll 8") for (int u = 0; u < K; ++u)
template <typename T, int B, Activation A, int K>
__attribute__((always_inline)) inline void sigmoid_k(typename Vec<T, B>::type* a) {
    typedef Vec<T, B> VT;
    typedef typename VT::type V;
    typedef typename VT::itype IV;
    typedef typename std::make_unsigned<typename VT::iscalar>::type U;  // modular shifts
    V y[K], t[K], f[K], f2[K], p[K];
    IV tb[K];
    TM_K a[u] = clamp_sym(a[u], T(VT::clamp));
    TM_K y[u] = a[u] * T(-1.4426950408889634);
    TM_K t[u] = y[u] + VT::round_magic;
    // The integer bits of t hold round(y) in the low mantissa bits.
    TM_K std::memcpy(&tb[u], &t[u], sizeof(IV));
    if (A == Activation::exact) {
        // exp(-a) to about one ulp: -a = n ln2 + r, |r| <= ln2/2 (Cody-Waite split
        // of ln2), exp(r) by its Taylor series (degree 13 for double, 7 for float:
        // truncation below 5e-18 and 6e-9 relative), then 1/(1 + exp(-a)) with a
        // true division.
        TM_K t[u] = t[u] - VT::round_magic;  // n
        if (sizeof(T) == 8) {
            TM_K f[u] = (T(0) - a[u]) - t[u] * T(0.693147180369123816490);
            TM_K f[u] = f[u] - t[u] * T(1.90821492927058770002e-10);
        } else {
            TM_K f[u] = (T(0) - a[u]) - t[u] * T(0.693359375);
            TM_K f[u] = f[u] - t[u] * T(-2.12194440e-4);
        }
        TM_K f2[u] = f[u] * f[u];
        if (sizeof(T) == 8) {
            TM_K {
                const V r = f[u], r2 = f2[u], r4 = r2 * r2;
                const V q0 = T(1.0) * r + T(1.0);
                const V q1 = T(1.0 / 6) * r + T(1.0 / 2);
                const V q2 = T(1.0 / 120) * r + T(1.0 / 24);
                const V q3 = T(1.0 / 5040) * r + T(1.0 / 720);
                const V q4 = T(1.0 / 362880) * r + T(1.0 / 40320);
                const V q5 = T(1.0 / 39916800) * r + T(1.0 / 3628800);
                const V q6 = T(1.0 / 6227020800.0) * r + T(1.0 / 479001600);
                const V u0 = (q3 * r2 + q2) * r4 + (q1 * r2 + q0);
                const V u1 = q6 * r4 + (q5 * r2 + q4);
                p[u] = u1 * (r4 * r4) + u0;
            }
        } else {
            TM_K {
                const V r = f[u], r2 = f2[u];
                const V q0 = T(1.0) * r + T(1.0);
                const V q1 = T(1.0 / 6) * r + T(1.0 / 2);
                const V q2 = T(1.0 / 120) * r + T(1.0 / 24);
                const V q3 = T(1.0 / 5040) * r + T(1.0 / 720);
                p[u] = (q3 * r2 + q2) * (r2 * r2) + (q1 * r2 + q0);
            }
        }
    } else {
        // 2^f, f = y - round(y), by Estrin's scheme.
        TM_K f[u] = y[u] - (t[u] - VT::round_magic);
        TM_K f2[u] = f[u] * f[u];
        TM_K {
            const V q01 = T(kP1) * f[u] + T(kP0);
            const V q23 = T(kP3) * f[u] + T(kP2);
            const V q456 = T(kP6) * f2[u] + (T(kP5) * f[u] + T(kP4));
            p[u] = (q23 * f2[u] + q01) + q456 * (f2[u] * f2[u]);
        }
    }
    TM_K {
        const IV eb = (tb[u] + static_cast<U>(VT::bias)) << VT::mant;
        V scale;
        std::memcpy(&scale, &eb, sizeof scale);
        t[u] = T(1) + p[u] * scale;
    }
    if (A == Activation::exact) {
        TM_K a[u] = T(1) / t[u];
    } else {
        TM_K a[u] = recip_fast(t[u]);
    }
}
#undef TM_K

template <typename T, int B, Activation A>
__attribute__((always_inline)) inline typename Vec<T, B>::type sigmoid_vec(typename Vec<T, B>::type a) {
    sigmoid_k<T, B, A, 1>(&a);
    return a;
}

template <typename T, int B, Activation A>
__attribute__((always_inline)) inline void sigmoid_array_impl(const T* in, T* out, std::size_t n) noexcept {
    typedef typename Vec<T, B>::type V;
    constexpr int NL = Vec<T, B>::lanes;
    std::size_t i = 0;
    for (; i + NL <= n; i += NL) {
        V v;
        std::memcpy(&v, in + i, sizeof v);
        v = sigmoid_vec<T, B, A>(v);
        std::memcpy(out + i, &v, sizeof v);
    }
    if (i < n) {
        V v = V{};
        for (std::size_t k = i; k < n; ++k) v[k - i] = in[k];
        v = sigmoid_vec<T, B, A>(v);
        for (std::size_t k = i; k < n; ++k) out[k] = v[k - i];
    }
}

#ifdef TM_DETECTOR_X86
template <typename T, Activation A>
__attribute__((target("avx2,fma"), noinline)) void sigmoid_array_avx2(const T* in, T* out, std::size_t n) noexcept {
    sigmoid_array_impl<T, 32, A>(in, out, n);
}
#endif

}  // namespace detail

/// The kernel's sigmoid on n values with the given activation and code path (for
/// measuring the approximation error; the path falls back to generic if absent).
template <typename T>
inline void sigmoid_array(const T* in, T* out, std::size_t n, Activation act, SimdPath path) noexcept {
#ifdef TM_DETECTOR_X86
    if (path == SimdPath::avx2 && cpu_has_avx2_fma()) {
        if (act == Activation::exact)
            detail::sigmoid_array_avx2<T, Activation::exact>(in, out, n);
        else
            detail::sigmoid_array_avx2<T, Activation::fast>(in, out, n);
        return;
    }
#else
    (void)path;
#endif
    if (act == Activation::exact)
        detail::sigmoid_array_impl<T, 16, Activation::exact>(in, out, n);
    else
        detail::sigmoid_array_impl<T, 16, Activation::fast>(in, out, n);
}

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
    static constexpr int L = 32 / int(sizeof(T));  // padding unit: lanes of the widest path

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
        n_pad_ = ((n_inst_ + L - 1) / L) * L;
        const std::size_t n_w1 = std::size_t(n_h_) * (n_in_ + 1);
        const std::size_t n_w = n_w1 + n_h_ + 2 * std::size_t(n_h_) + 2 + 2 * std::size_t(n_in_);
        // State: xs_ (n_in, n_pad) inputs of one tick, prev_, yslip_, and the chunk
        // buffers of run(): xch_ (kChunk, n_in, n_pad), ych_ (kChunk, 2, n_pad).
        const std::size_t n_state = std::size_t(n_in_) * n_pad_ + 2 * std::size_t(n_pad_) +
                                    std::size_t(kChunk) * (n_in_ + 2) * n_pad_;
        // Replicated weights: per hidden unit, n_in + 4 slots of L copies
        // [b1, w1[j, 0..n_in-1], w1[j, n_in], w2[0, j], w2[1, j]].
        const std::size_t n_rep = std::size_t(n_h_) * (n_in_ + 4) * L;
        const std::size_t count = n_rep + n_w + n_state + 64;
        void* mem = std::aligned_alloc(64, ((count * sizeof(T) + 63) / 64) * 64);
        if (!mem) throw std::bad_alloc();
        buf_.reset(mem);
        T* p = static_cast<T*>(mem);
        std::memset(p, 0, count * sizeof(T));
        // Replicated weights and state first (vector-aligned), then weights.
        wrep_ = p;
        p += n_rep;
        xs_ = p;
        p += std::size_t(n_in_) * n_pad_;
        prev_ = p;
        p += n_pad_;
        yslip_ = p;
        p += n_pad_;
        xch_ = p;
        p += std::size_t(kChunk) * n_in_ * n_pad_;
        ych_ = p;
        p += std::size_t(kChunk) * 2 * n_pad_;
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
        for (int j = 0; j < n_h_; ++j) {
            T* slot = wrep_ + std::size_t(j) * (n_in_ + 4) * L;
            for (int l = 0; l < L; ++l) {
                slot[l] = b1_[j];
                for (int i = 0; i <= n_in_; ++i) slot[(1 + i) * L + l] = w1_[std::size_t(j) * (n_in_ + 1) + i];
                slot[(n_in_ + 2) * L + l] = w2_[j];
                slot[(n_in_ + 3) * L + l] = w2_[n_h_ + j];
            }
        }
        path_ = cpu_has_avx2_fma() ? SimdPath::avx2 : SimdPath::generic;
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
    SimdPath simd_path() const noexcept { return path_; }
    /// Select a code path; returns false (and changes nothing) if the CPU lacks it.
    bool set_simd_path(SimdPath p) noexcept {
        if (p == SimdPath::avx2 && !cpu_has_avx2_fma()) return false;
        path_ = p;
        return true;
    }

    /// Recurrent state: y_pred(t-1) of every instance (n_instances values).
    void get_state(T* out) const noexcept {
        for (int r = 0; r < n_inst_; ++r) out[r] = prev_[r];
    }
    void set_state(const T* in) noexcept {
        for (int r = 0; r < n_inst_; ++r) prev_[r] = in[r];
    }
    void reset() noexcept {
        for (int r = 0; r < n_pad_; ++r) prev_[r] = T(0);
    }

    /// One tick of all instances. in: (n_instances, n_inputs) row-major raw features;
    /// out: (n_instances, 3) row-major [y_slip, y_non, y_pred].
    void step(const T* in, T* out) noexcept {
        for (int r = 0; r < n_inst_; ++r)
            for (int i = 0; i < n_in_; ++i) xs_[std::size_t(i) * n_pad_ + r] = (in[r * n_in_ + i] - mean_[i]) * gain_[i];
        tick(xs_, yslip_, prev_, 1, n_pad_);
        for (int r = 0; r < n_inst_; ++r) {
            out[3 * r + 0] = yslip_[r];
            out[3 * r + 1] = T(1) - yslip_[r];
            out[3 * r + 2] = prev_[r];
        }
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
        // Chunks of kChunk ticks: normalise and transpose the inputs into the SoA
        // chunk buffer (reading each input row sequentially), run the ticks with
        // the state in registers, then write the outputs row by row.
        const std::size_t tick_in = std::size_t(n_in_) * n_pad_;
        for (std::ptrdiff_t t0 = 0; t0 < n; t0 += kChunk) {
            const int m = int(n - t0 < kChunk ? n - t0 : kChunk);
            for (int r = 0; r < n_inst_; ++r)
                for (int i = 0; i < n_in_; ++i) {
                    const T* src = x + r * sr + i * si + t0 * st;
                    T* dst = xch_ + std::size_t(i) * n_pad_ + r;
                    const T mu = mean_[i], g = gain_[i];
                    for (int k = 0; k < m; ++k) dst[k * tick_in] = (src[k * st] - mu) * g;
                }
            tick(xch_, ych_, ych_ + n_pad_, m, 2 * n_pad_);
            for (int r = 0; r < n_inst_; ++r) {
                T* ys = y_slip + r * ld + t0;
                T* yn = y_non + r * ld + t0;
                T* yp = y_pred + r * ld + t0;
                for (int k = 0; k < m; ++k) {
                    const T a = ych_[std::size_t(k) * 2 * n_pad_ + r];
                    ys[k] = a;
                    yn[k] = T(1) - a;
                    yp[k] = ych_[std::size_t(k) * 2 * n_pad_ + n_pad_ + r];
                }
            }
        }
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
        double best = std::numeric_limits<double>::infinity();
        volatile T sink = 0;
        for (int rep = 0; rep < repeats; ++rep) {
            const auto t0 = std::chrono::steady_clock::now();
            if (scalar) {
                for (long it = 0; it < n_iter; ++it)
                    for (int r = 0; r < n_inst_; ++r) step_one(r, in + r * n_in_, out + 3 * r);
            } else {
                for (long it = 0; it < n_iter; ++it) step(in, out);  // ticks chained through the state
            }
            const auto t1 = std::chrono::steady_clock::now();
            sink = sink + out[0];
            const double ns = std::chrono::duration<double, std::nano>(t1 - t0).count() / double(n_iter);
            if (ns < best) best = ns;
        }
        set_state(saved);
        return best;
    }

private:
    T sig_scalar(T a) const noexcept {
        return act_ == Activation::exact ? detail::sigmoid_exact_scalar<T>(a) : detail::sigmoid_fast_scalar<T>(a);
    }

    // m ticks: inputs xs + k * n_in * n_pad (layout (n_in, n_pad)), outputs y_slip
    // at ys + k * out_stride and y_pred at yp + k * out_stride; state in prev_.
    void tick(const T* xs, T* ys, T* yp, int m, std::size_t out_stride) noexcept {
#ifdef TM_DETECTOR_X86
        if (path_ == SimdPath::avx2) {
            if (act_ == Activation::exact)
                tick_avx2_exact(xs, ys, yp, m, out_stride);
            else
                tick_avx2_fast(xs, ys, yp, m, out_stride);
            return;
        }
#endif
        if (act_ == Activation::exact)
            tick_dispatch<16, Activation::exact>(xs, ys, yp, m, out_stride);
        else
            tick_dispatch<16, Activation::fast>(xs, ys, yp, m, out_stride);
    }

#ifdef TM_DETECTOR_X86
    __attribute__((target("avx2,fma"), noinline)) void tick_avx2_exact(const T* xs, T* ys, T* yp, int m,
                                                                       std::size_t os) noexcept {
        tick_dispatch<32, Activation::exact>(xs, ys, yp, m, os);
    }
    __attribute__((target("avx2,fma"), noinline)) void tick_avx2_fast(const T* xs, T* ys, T* yp, int m,
                                                                      std::size_t os) noexcept {
        tick_dispatch<32, Activation::fast>(xs, ys, yp, m, os);
    }
#endif

    // The paper's network has 4 inputs: that size is unrolled at compile time.
    template <int B, Activation A>
    __attribute__((always_inline)) inline void tick_dispatch(const T* xs, T* ys, T* yp, int m,
                                                             std::size_t os) noexcept {
        if (n_in_ == 4)
            tick_impl<B, A, 4>(xs, ys, yp, m, os);
        else
            tick_impl<B, A, 0>(xs, ys, yp, m, os);
    }

    // Core: instances sit in the lanes of B-byte vectors; for each lane block the
    // state p stays in a register over the m ticks. The input part of each
    // pre-activation does not depend on the state, so the recurrent dependency
    // chain per tick is one FMA, the hidden sigmoid, the output sum and the
    // output sigmoid.
    template <int B, Activation A, int NIN>
    __attribute__((always_inline)) inline void tick_impl(const T* xs, T* ys_out, T* yp_out, int m,
                                                         std::size_t os) noexcept {
        typedef typename detail::Vec<T, B>::type V;
        constexpr int NL = detail::Vec<T, B>::lanes;
        const std::size_t tick_in = std::size_t(NIN > 0 ? NIN : n_in_) * n_pad_;
        if (n_inst_ <= NL) {
            // One lane block: the state stays in a register over the m ticks.
            V p;
            std::memcpy(&p, prev_, sizeof(V));
            for (int k = 0; k < m; ++k) {
                V ys;
                one_tick<B, A, NIN>(xs + k * tick_in, p, ys);
                std::memcpy(ys_out + k * os, &ys, sizeof(V));
                std::memcpy(yp_out + k * os, &p, sizeof(V));
            }
            std::memcpy(prev_, &p, sizeof(V));
            return;
        }
        // Several lane blocks: ticks outside, blocks inside, so that the blocks'
        // dependency chains overlap.
        for (int k = 0; k < m; ++k) {
            for (int r0 = 0; r0 < n_inst_; r0 += NL) {
                V p, ys;
                std::memcpy(&p, prev_ + r0, sizeof(V));
                one_tick<B, A, NIN>(xs + k * tick_in + r0, p, ys);
                std::memcpy(prev_ + r0, &p, sizeof(V));
                std::memcpy(ys_out + k * os + r0, &ys, sizeof(V));
                std::memcpy(yp_out + k * os + r0, &p, sizeof(V));
            }
        }
    }

    // One tick of one lane block: xk points at its inputs (layout (n_in, n_pad));
    // p is the state in and y_pred out. Hidden units go in groups of G whose
    // sigmoids are interleaved; weights come from the replicated slots.
    template <int B, Activation A, int NIN>
    __attribute__((always_inline)) inline void one_tick(const T* xk, typename detail::Vec<T, B>::type& p,
                                                        typename detail::Vec<T, B>::type& ys) const noexcept {
        typedef typename detail::Vec<T, B>::type V;
        constexpr int G = 4;
        const int nin = NIN > 0 ? NIN : n_in_, nh = n_h_;
        const std::size_t slot = std::size_t(nin + 4) * L;
        V x[NIN > 0 ? NIN : 64];
        for (int i = 0; i < nin; ++i) std::memcpy(&x[i], xk + std::size_t(i) * n_pad_, sizeof(V));
        V o0[2] = {V{} + b2_[0], V{}};
        V o1[2] = {V{} + b2_[1], V{}};
        int j = 0;
        for (; j + G <= nh; j += G) group<B, A, NIN, G>(j, x, p, o0, o1, slot);
        for (; j < nh; ++j) group<B, A, NIN, 1>(j, x, p, o0, o1, slot);
        V out[2] = {o0[0] + o0[1], o1[0] + o1[1]};
        detail::sigmoid_k<T, B, A, 2>(out);
        ys = out[0];
        p = out[1];
    }

    template <int B, Activation A, int NIN, int G>
    __attribute__((always_inline)) inline void group(int j, const typename detail::Vec<T, B>::type* x,
                                                     typename detail::Vec<T, B>::type p,
                                                     typename detail::Vec<T, B>::type* o0,
                                                     typename detail::Vec<T, B>::type* o1,
                                                     std::size_t slot) const noexcept {
        typedef typename detail::Vec<T, B>::type V;
        const int nin = NIN > 0 ? NIN : n_in_;
        const T* __restrict w = wrep_ + std::size_t(j) * slot;
        V a[G];
        _Pragma("GCC unroll 8") for (int g = 0; g < G; ++g) {
            const T* wg = w + g * slot;
            V acc = load<V>(wg);
            for (int i = 0; i < nin; ++i) acc += load<V>(wg + (1 + i) * L) * x[i];
            a[g] = acc + load<V>(wg + (1 + nin) * L) * p;
        }
        detail::sigmoid_k<T, B, A, G>(a);
        _Pragma("GCC unroll 8") for (int g = 0; g < G; ++g) {
            const T* wg = w + g * slot;
            o0[g & 1] += load<V>(wg + (2 + nin) * L) * a[g];
            o1[g & 1] += load<V>(wg + (3 + nin) * L) * a[g];
        }
    }

    template <typename V>
    static __attribute__((always_inline)) inline V load(const T* ptr) noexcept {
        V v;
        std::memcpy(&v, ptr, sizeof(V));
        return v;
    }

    int n_in_, n_h_, n_inst_, n_pad_ = 0;
    Activation act_;
    SimdPath path_ = SimdPath::generic;
    std::unique_ptr<void, detail::AlignedFree> buf_;
    T* wrep_ = nullptr;
    static constexpr int kChunk = 64;
    T* xs_ = nullptr;
    T* xch_ = nullptr;
    T* ych_ = nullptr;
    T* prev_ = nullptr;
    T* yslip_ = nullptr;
    T* w1_ = nullptr;
    T* b1_ = nullptr;
    T* w2_ = nullptr;
    T* b2_ = nullptr;
    T* mean_ = nullptr;
    T* gain_ = nullptr;
};

}  // namespace detector
}  // namespace tm_core

#pragma GCC diagnostic pop
