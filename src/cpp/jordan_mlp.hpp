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
// (one per ridge) share one weight set. The SIMD code is written with GCC vector
// extensions and compiled twice: for the baseline ISA and for AVX2+FMA; the AVX2
// path is selected at construction with __builtin_cpu_supports. step() and run()
// go through the same compiled function, so they agree bit for bit. No pybind11
// or Python in this header.
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
// Activations: Activation::exact is accurate to a few ulp (exp with Cody-Waite
// range reduction, a two-constant split of ln2 except for float on the AVX2 path,
// see sigmoid_k, and a near-minimax polynomial, degree 11 for double, 6 for
// float, then a true division; the scalar step_one uses std::exp);
// Activation::fast uses 2^y = 2^n * P(f), |f| <= 1/2 (degree 6 for double,
// relative error < 2e-9; degree 5 for float, < 1.1e-7) and, for float on x86, a
// reciprocal estimate with one Newton step. Both evaluate the polynomials by
// Estrin's scheme. Measured over 2e6 points in [-100, 100] against
// scipy.special.expit: |error| <= 1.7e-16 exact double, <= 4.7e-10 fast double,
// <= 8.9e-8 exact float, <= 1.9e-7 fast float (1.4e-7 on the AVX2 path).
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

#if defined(__clang__)
#define TM_DETECTOR_SHUF(V, IV, a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)
#else
#define TM_DETECTOR_SHUF(V, IV, a, b, ...) __builtin_shuffle(a, b, IV{__VA_ARGS__})
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
    // 1.5 * 2^23 + 127: y + magic rounds y to an integer n (in the default
    // rounding mode) and leaves n + 127 in the low mantissa bits, so that those
    // bits shifted to the exponent field are 2^n.
    static constexpr float round_magic = 12583039.0f;
    static constexpr int mant = 23;
};

template <>
struct Scalar<double> {
    typedef std::int64_t iscalar;
    static constexpr double clamp = 600.0;
    static constexpr double round_magic = 6755399441056767.0;  // 1.5 * 2^52 + 1023, as above
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

// Polynomial coefficients, lowest degree first.
// fast: 2^f on [-1/2, 1/2]. Double: degree 6, relative error < 2e-9 (least
// squares on Chebyshev nodes). Float: degree 5 with c0 = 1, relative error
// < 1.1e-7 with the coefficients rounded to float (Lawson minimax); one degree
// less than double because float rounding (6e-8) dominates anyway.
template <typename T>
struct FastPoly;
template <>
struct FastPoly<double> {
    static constexpr int degree = 6;
    static constexpr double c[7] = {1.0000000005920207,    0.69314720560051013,  0.24022646608714027,
                                    0.055503289975174459,  0.0096185195343476276, 0.001339986036321298,
                                    0.00015337576834253096};
};
template <>
struct FastPoly<float> {
    static constexpr int degree = 5;
    static constexpr double c[6] = {1.0,
                                    0.6931470036506653,
                                    0.24022242426872253,
                                    0.05550733581185341,
                                    0.009671512991189957,
                                    0.001326472731307149};
};
// exact: exp(r) on [-ln2/2, ln2/2], near-minimax with c0 = c1 = 1. Double: degree
// 11 (Chebyshev fit, relative error 2e-17 with double coefficients); float:
// degree 6 (Lawson minimax, 4e-9 with float coefficients).
template <typename T>
struct ExpPoly;
template <>
struct ExpPoly<double> {
    static constexpr int degree = 11;
    static constexpr double c[12] = {1.0,
                                     1.0,
                                     0.5000000000000019,
                                     0.1666666666666668,
                                     0.0416666666664881,
                                     0.008333333333319601,
                                     0.0013888888952314775,
                                     0.00019841269890047113,
                                     2.4801485482328494e-05,
                                     2.755724091857897e-06,
                                     2.763263963904103e-07,
                                     2.5110037605963777e-08};
};
template <>
struct ExpPoly<float> {
    static constexpr int degree = 6;
    static constexpr double c[7] = {1.0,
                                    1.0,
                                    0.4999999403953552,
                                    0.1666652113199234,
                                    0.04166838899254799,
                                    0.008368710055947304,
                                    0.001381461275741458};
};

// sum_k s_k c[k] x^k (s_k = -1 for odd k when Neg, that is P(-x)) by Estrin's
// scheme (degree N <= 15): a dependency chain of about log2(N) + 1 multiply-adds
// instead of N for Horner's rule, for a few more operations. Measured: as fast
// as Horner's rule in the AVX2 kernel and clearly faster in the baseline SSE2
// kernel (no FMA there, so Horner's chain is twice as long).
template <typename T, int N, bool Neg>
__attribute__((always_inline)) inline T coef(const double* c, int k) {
    return T(k > N ? 0.0 : (Neg && (k & 1) ? -c[k] : c[k]));
}

template <typename T, int N, bool Neg, typename V>
__attribute__((always_inline)) inline V estrin(const double* c, V x) {
    const auto cf = [c](int k) __attribute__((always_inline)) { return coef<T, N, Neg>(c, k); };
    V q[8];
    constexpr int NQ = (N + 2) / 2;
    _Pragma("GCC unroll 8") for (int k = 0; k < NQ; ++k) q[k] = (2 * k + 1 <= N) ? cf(2 * k + 1) * x + cf(2 * k)
                                                                                  : V{} + cf(2 * k);
    V x2 = x * x;
    int n = NQ;
    _Pragma("GCC unroll 4") for (int lvl = 0; lvl < 3 && n > 1; ++lvl) {
        _Pragma("GCC unroll 8") for (int k = 0; 2 * k < n; ++k) q[k] = (2 * k + 1 < n) ? q[2 * k + 1] * x2 + q[2 * k]
                                                                                       : q[2 * k];
        n = (n + 1) / 2;
        x2 = x2 * x2;
    }
    return q[0];
}

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
    const T p = estrin<T, FastPoly<T>::degree, false>(FastPoly<T>::c, f);
    const I eb = static_cast<I>(tb << Scalar<T>::mant);
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
// sigmoid is a long chain, and the out-of-order window holds only a few of them
// at a time). Scaled (fast only): the argument is already y = -a log2(e) (the
// kernel folds the factor into the weights), which saves two multiply-adds.
#define TM_K _Pragma("GCC unroll 16") for (int u = 0; u < K; ++u)
template <typename T, int B, Activation A, int K, bool Scaled = false>
__attribute__((always_inline)) inline void sigmoid_k(typename Vec<T, B>::type* a) {
    typedef Vec<T, B> VT;
    typedef typename VT::type V;
    typedef typename VT::itype IV;
    static_assert(!Scaled || A == Activation::fast, "scaled arguments are for the fast sigmoid");
    V y[K], t[K], p[K];
    IV tb[K];
    if (Scaled) {
        TM_K y[u] = clamp_sym(a[u], T(VT::clamp * 1.4426950408889634));
        TM_K t[u] = y[u] + VT::round_magic;
    } else {
        TM_K a[u] = clamp_sym(a[u], T(VT::clamp));
        TM_K y[u] = a[u] * T(-1.4426950408889634);
        TM_K t[u] = y[u] + VT::round_magic;
    }
    // The low mantissa bits of t hold round(y) + bias.
    TM_K std::memcpy(&tb[u], &t[u], sizeof(IV));
    TM_K t[u] = t[u] - VT::round_magic;  // n = round(y)
    if (A == Activation::exact) {
        // exp(-a) to about one ulp: -a = n ln2 - s, |s| <= ln2/2 (Cody-Waite split
        // of ln2, s = a + n ln2), exp(-s) by the polynomial, then 1/(1 + exp(-a))
        // with a true division.
        if (sizeof(T) == 8) {
            TM_K y[u] = t[u] * T(0.693147180369123816490) + a[u];
            TM_K y[u] = t[u] * T(1.90821492927058770002e-10) + y[u];
        } else if (B == 32) {
            // Float on the FMA path: one fused step with ln2 rounded to float. Its
            // error, |n| * 1.9e-9 relative in exp(-a), exceeds a float ulp only for
            // |n| > 30, where the sigmoid is below 1e-9 or rounds to 1: there the
            // relative error grows from 2.3e-7 to 3.3e-7 (measured); the absolute
            // error bound (8.9e-8) does not change. One multiply-add less is 7%
            // of the float tick.
            TM_K y[u] = t[u] * T(0.693147180559945309) + a[u];
        } else {
            TM_K y[u] = t[u] * T(0.693359375) + a[u];
            TM_K y[u] = t[u] * T(-2.12194440e-4) + y[u];
        }
        TM_K p[u] = estrin<T, ExpPoly<T>::degree, true>(ExpPoly<T>::c, y[u]);
    } else {
        TM_K y[u] = y[u] - t[u];  // f = y - n, |f| <= 1/2 (exact)
        TM_K p[u] = estrin<T, FastPoly<T>::degree, false>(FastPoly<T>::c, y[u]);
    }
    TM_K {
        const IV eb = tb[u] << VT::mant;
        V scale;
        std::memcpy(&scale, &eb, sizeof scale);
        t[u] = p[u] * scale + T(1);
    }
    if (A == Activation::exact) {
        TM_K a[u] = T(1) / t[u];
    } else {
        TM_K a[u] = recip_fast(t[u]);
    }
}
#undef TM_K

// The sigmoid as the kernel's hidden layer computes it (for the fast activation
// the kernel's pre-activation is already scaled by -log2(e); here one multiply).
template <typename T, int B, Activation A>
__attribute__((always_inline)) inline typename Vec<T, B>::type sigmoid_vec(typename Vec<T, B>::type a) {
    if (A == Activation::fast) {
        a = a * T(-1.4426950408889634);
        sigmoid_k<T, B, Activation::fast, 1, true>(&a);
    } else {
        sigmoid_k<T, B, A, 1>(&a);
    }
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

// One value from memory into every lane (a single broadcast load on x86).
template <typename T, int B>
__attribute__((always_inline)) inline typename Vec<T, B>::type bcast(const T* p) {
    return typename Vec<T, B>::type{} + *p;
}
#ifdef TM_DETECTOR_X86
template <>
__attribute__((always_inline)) inline Vec<float, 16>::type bcast<float, 16>(const float* p) {
    return (Vec<float, 16>::type)_mm_load1_ps(p);
}
template <>
__attribute__((always_inline)) inline Vec<double, 16>::type bcast<double, 16>(const double* p) {
    return (Vec<double, 16>::type)_mm_load1_pd(p);
}
// The 32-byte versions are only ever inlined into the AVX2 tick.
template <>
__attribute__((always_inline)) inline Vec<float, 32>::type bcast<float, 32>(const float* p) {
    return (Vec<float, 32>::type)__builtin_ia32_vbroadcastss256(p);
}
template <>
__attribute__((always_inline)) inline Vec<double, 32>::type bcast<double, 32>(const double* p) {
    return (Vec<double, 32>::type)__builtin_ia32_vbroadcastsd256(p);
}
#endif

// Transpose-and-add: s[0..lanes-1] -> one vector whose lane k is the sum of the
// lanes of s[k]. log2(lanes) levels of two in-lane shuffles and one add per pair.
template <typename T, int B>
struct Reduce;
template <>
struct Reduce<float, 32> {
    typedef Vec<float, 32>::type V;
    typedef Vec<float, 32>::itype IV;
    static __attribute__((always_inline)) inline V pair(V x, V y, int lvl) {
        if (lvl < 2)  // [x0+x1, x2+x3, y0+y1, y2+y3 | ...]
            return TM_DETECTOR_SHUF(V, IV, x, y, 0, 2, 8, 10, 4, 6, 12, 14) +
                   TM_DETECTOR_SHUF(V, IV, x, y, 1, 3, 9, 11, 5, 7, 13, 15);
        return TM_DETECTOR_SHUF(V, IV, x, y, 0, 1, 2, 3, 8, 9, 10, 11) +
               TM_DETECTOR_SHUF(V, IV, x, y, 4, 5, 6, 7, 12, 13, 14, 15);
    }
};
template <>
struct Reduce<float, 16> {
    typedef Vec<float, 16>::type V;
    typedef Vec<float, 16>::itype IV;
    static __attribute__((always_inline)) inline V pair(V x, V y, int) {
        return TM_DETECTOR_SHUF(V, IV, x, y, 0, 2, 4, 6) + TM_DETECTOR_SHUF(V, IV, x, y, 1, 3, 5, 7);
    }
};
template <>
struct Reduce<double, 32> {
    typedef Vec<double, 32>::type V;
    typedef Vec<double, 32>::itype IV;
    static __attribute__((always_inline)) inline V pair(V x, V y, int lvl) {
        if (lvl == 0) return TM_DETECTOR_SHUF(V, IV, x, y, 0, 4, 2, 6) + TM_DETECTOR_SHUF(V, IV, x, y, 1, 5, 3, 7);
        return TM_DETECTOR_SHUF(V, IV, x, y, 0, 1, 4, 5) + TM_DETECTOR_SHUF(V, IV, x, y, 2, 3, 6, 7);
    }
};
template <>
struct Reduce<double, 16> {
    typedef Vec<double, 16>::type V;
    typedef Vec<double, 16>::itype IV;
    static __attribute__((always_inline)) inline V pair(V x, V y, int) {
        return TM_DETECTOR_SHUF(V, IV, x, y, 0, 2) + TM_DETECTOR_SHUF(V, IV, x, y, 1, 3);
    }
};

// One level of the transpose-and-add over the first M entries of s (the others
// are zero); all bounds are compile-time so that s stays in registers.
template <typename T, int B, int M, int Lvl>
__attribute__((always_inline)) inline void reduce_level(typename Vec<T, B>::type* s) {
    typedef typename Vec<T, B>::type V;
    _Pragma("GCC unroll 8") for (int k = 0; k < (M + 1) / 2; ++k) s[k] =
        Reduce<T, B>::pair(s[2 * k], 2 * k + 1 < M ? s[2 * k + 1] : V{}, Lvl);
}

// s: the first N entries are live; returns lane k = sum of the lanes of s[k].
template <typename T, int B, int N>
__attribute__((always_inline)) inline typename Vec<T, B>::type reduce_lanes(typename Vec<T, B>::type* s) {
    constexpr int NL = Vec<T, B>::lanes;
    static_assert(N <= NL, "too many sums for one vector");
    reduce_level<T, B, N, 0>(s);
    if (NL >= 4) reduce_level<T, B, (N + 1) / 2, 1>(s);
    if (NL >= 8) reduce_level<T, B, (N + 3) / 4, 2>(s);
    return s[0];
}


// In-place transpose of lanes x lanes values: afterwards lane k of v[q] is what
// lane q of v[k] was. Used to write the block outputs tick-contiguous.
template <typename T, int B>
struct Transpose;
template <>
struct Transpose<double, 16> {
    typedef Vec<double, 16>::type V;
    typedef Vec<double, 16>::itype IV;
    static __attribute__((always_inline)) inline void run(V* v) {
        const V a = TM_DETECTOR_SHUF(V, IV, v[0], v[1], 0, 2), b = TM_DETECTOR_SHUF(V, IV, v[0], v[1], 1, 3);
        v[0] = a;
        v[1] = b;
    }
};
template <>
struct Transpose<double, 32> {
    typedef Vec<double, 32>::type V;
    typedef Vec<double, 32>::itype IV;
    static __attribute__((always_inline)) inline void run(V* v) {
        const V t0 = TM_DETECTOR_SHUF(V, IV, v[0], v[1], 0, 4, 2, 6), t1 = TM_DETECTOR_SHUF(V, IV, v[0], v[1], 1, 5, 3, 7);
        const V t2 = TM_DETECTOR_SHUF(V, IV, v[2], v[3], 0, 4, 2, 6), t3 = TM_DETECTOR_SHUF(V, IV, v[2], v[3], 1, 5, 3, 7);
        v[0] = TM_DETECTOR_SHUF(V, IV, t0, t2, 0, 1, 4, 5);
        v[1] = TM_DETECTOR_SHUF(V, IV, t1, t3, 0, 1, 4, 5);
        v[2] = TM_DETECTOR_SHUF(V, IV, t0, t2, 2, 3, 6, 7);
        v[3] = TM_DETECTOR_SHUF(V, IV, t1, t3, 2, 3, 6, 7);
    }
};
template <>
struct Transpose<float, 16> {
    typedef Vec<float, 16>::type V;
    typedef Vec<float, 16>::itype IV;
    static __attribute__((always_inline)) inline void run(V* v) {
        const V t0 = TM_DETECTOR_SHUF(V, IV, v[0], v[1], 0, 4, 1, 5), t1 = TM_DETECTOR_SHUF(V, IV, v[0], v[1], 2, 6, 3, 7);
        const V t2 = TM_DETECTOR_SHUF(V, IV, v[2], v[3], 0, 4, 1, 5), t3 = TM_DETECTOR_SHUF(V, IV, v[2], v[3], 2, 6, 3, 7);
        v[0] = TM_DETECTOR_SHUF(V, IV, t0, t2, 0, 1, 4, 5);
        v[1] = TM_DETECTOR_SHUF(V, IV, t0, t2, 2, 3, 6, 7);
        v[2] = TM_DETECTOR_SHUF(V, IV, t1, t3, 0, 1, 4, 5);
        v[3] = TM_DETECTOR_SHUF(V, IV, t1, t3, 2, 3, 6, 7);
    }
};
template <>
struct Transpose<float, 32> {
    typedef Vec<float, 32>::type V;
    typedef Vec<float, 32>::itype IV;
    static __attribute__((always_inline)) inline void run(V* v) {
        // 4 x 4 transposes inside the 128-bit halves, then the off-diagonal 4 x 4
        // blocks swap halves.
        V t[8], u[8];
        _Pragma("GCC unroll 4") for (int p = 0; p < 8; p += 2) {
            t[p] = TM_DETECTOR_SHUF(V, IV, v[p], v[p + 1], 0, 8, 1, 9, 4, 12, 5, 13);
            t[p + 1] = TM_DETECTOR_SHUF(V, IV, v[p], v[p + 1], 2, 10, 3, 11, 6, 14, 7, 15);
        }
        _Pragma("GCC unroll 2") for (int p = 0; p < 8; p += 4) {
            u[p] = TM_DETECTOR_SHUF(V, IV, t[p], t[p + 2], 0, 1, 8, 9, 4, 5, 12, 13);
            u[p + 1] = TM_DETECTOR_SHUF(V, IV, t[p], t[p + 2], 2, 3, 10, 11, 6, 7, 14, 15);
            u[p + 2] = TM_DETECTOR_SHUF(V, IV, t[p + 1], t[p + 3], 0, 1, 8, 9, 4, 5, 12, 13);
            u[p + 3] = TM_DETECTOR_SHUF(V, IV, t[p + 1], t[p + 3], 2, 3, 10, 11, 6, 7, 14, 15);
        }
        _Pragma("GCC unroll 4") for (int q = 0; q < 4; ++q) {
            v[q] = TM_DETECTOR_SHUF(V, IV, u[q], u[q + 4], 0, 1, 2, 3, 8, 9, 10, 11);
            v[q + 4] = TM_DETECTOR_SHUF(V, IV, u[q], u[q + 4], 4, 5, 6, 7, 12, 13, 14, 15);
        }
    }
};

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
        const std::size_t count = 2 * n_col + n_w + n_state + 64;
        void* mem = std::aligned_alloc(64, ((count * sizeof(T) + 63) / 64) * 64);
        if (!mem) throw std::bad_alloc();
        buf_.reset(mem);
        T* p = static_cast<T*>(mem);
        std::memset(p, 0, count * sizeof(T));
        wcol_[0] = p;
        p += n_col;
        wcol_[1] = p;
        p += n_col;
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
        for (int r = 0; r < n_inst_; ++r) prev_[r] = T(0);
    }

    /// One tick of all instances. in: (n_instances, n_inputs) row-major raw features;
    /// out: (n_instances, 3) row-major [y_slip, y_non, y_pred].
    void step(const T* in, T* out) noexcept { run(in, n_in_, 1, 0, 1, out, out + 1, out + 2, 3); }

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
        const Io io{x, sr, si, st, n, y_slip, y_non, y_pred, ld};
#ifdef TM_DETECTOR_X86
        if (path_ == SimdPath::avx2) {
            if (act_ == Activation::exact)
                run_avx2_exact(io);
            else
                run_avx2_fast(io);
            return;
        }
#endif
        if (act_ == Activation::exact)
            run_generic_exact(io);
        else
            run_generic_fast(io);
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
    struct Io {
        const T* x;
        std::ptrdiff_t sr, si, st, n;
        T *ys, *yn, *yp;
        std::ptrdiff_t ld;
    };

    T sig_scalar(T a) const noexcept {
        return act_ == Activation::exact ? detail::sigmoid_exact_scalar<T>(a) : detail::sigmoid_fast_scalar<T>(a);
    }

    // One entry point per code path and activation, so that step() and run()
    // execute the same machine code and agree bit for bit.
#ifdef TM_DETECTOR_X86
    __attribute__((target("avx2,fma"), noinline)) void run_avx2_exact(const Io& io) noexcept {
        run_dispatch<32, Activation::exact>(io);
    }
    __attribute__((target("avx2,fma"), noinline)) void run_avx2_fast(const Io& io) noexcept {
        run_dispatch<32, Activation::fast>(io);
    }
#endif
    __attribute__((noinline)) void run_generic_exact(const Io& io) noexcept { run_dispatch<16, Activation::exact>(io); }
    __attribute__((noinline)) void run_generic_fast(const Io& io) noexcept { run_dispatch<16, Activation::fast>(io); }

    // The paper's network (4 inputs, 16 hidden units) is unrolled at compile time.
    template <int B, Activation A>
    __attribute__((always_inline)) inline void run_dispatch(const Io& io) noexcept {
        constexpr int NL = detail::Vec<T, B>::lanes;
        if (n_in_ == 4 && hp_ == 16)
            run_impl<B, A, 4, 16 / NL>(io);
        else
            run_impl<B, A, 0, 0>(io);
    }

    template <int B, Activation A, int NIN, int NV>
    __attribute__((always_inline)) inline void run_impl(const Io& io) noexcept {
        const int nin = NIN > 0 ? NIN : n_in_;
        if (io.n == 1 && io.si == 1 && io.sr == nin) {
            // One tick of contiguous features (step()): normalise into xs_.
            const int ni = n_inst_;
            const T* __restrict xin = io.x;
            T* __restrict xs = xs_;
            if (NIN == 4) {
                // One 4-lane vector per instance.
                typedef typename detail::Vec<T, 4 * sizeof(T)>::type V4;
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
                const T* __restrict mu = mean_;
                const T* __restrict g = gain_;
                for (int r = 0; r < ni; ++r)
                    for (int i = 0; i < nin; ++i) xs[r * nin + i] = (xin[r * nin + i] - mu[i]) * g[i];
            }
            tick_impl<B, A, NIN, NV>(xs_, nin, 1, 0, 1, ych_);
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
        typedef typename detail::Vec<T, B>::type V;
        constexpr int NL = detail::Vec<T, B>::lanes;
        constexpr int GM = NL / 2 > 0 ? NL / 2 : 1;
        constexpr int CL = 64 / int(sizeof(T));  // values per cache line
        const int ni = n_inst_;
        const int ng = (ni + GM - 1) / GM;
        const int gsz = (ni + ng - 1) / ng;  // group size, as in tick_impl
        const std::ptrdiff_t ld = io.ld;
        for (std::ptrdiff_t t0 = 0; t0 < io.n; t0 += kChunk) {
            const int m = int(io.n - t0 < kChunk ? io.n - t0 : kChunk);
            const bool more = t0 + 2 * kChunk <= io.n;
            for (int r = 0; r < ni; ++r)
                for (int i = 0; i < nin; ++i) {
                    const T* __restrict src = io.x + r * io.sr + i * io.si + t0 * io.st;
                    T* __restrict dst = xch_ + std::size_t(r * nin + i) * kChunk;
                    const T mu = mean_[i], g = gain_[i];
                    int k = 0;
                    if (io.st == 1) {
                        if (more)
                            for (int c = 0; c < kChunk; c += CL) __builtin_prefetch(src + kChunk + c, 0, 3);
                        for (; k + NL <= m; k += NL) {
                            V v = load<V>(src + k);
                            v = (v - mu) * g;
                            std::memcpy(dst + k, &v, sizeof v);
                        }
                    }
                    for (; k < m; ++k) dst[k] = (src[k * io.st] - mu) * g;
                }
            tick_impl<B, A, NIN, NV>(xch_, std::ptrdiff_t(nin) * kChunk, kChunk, 1, m, ych_);
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
                    _Pragma("GCC unroll 8") for (int q = 0; q < NL; ++q) v[q] = load<V>(u + (k + q) * urec_);
                    detail::Transpose<T, B>::run(v);
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
    template <int B, Activation A, int NIN, int NV>
    __attribute__((always_inline)) inline void tick_impl(const T* xs, std::ptrdiff_t xr, std::ptrdiff_t xi,
                                                         std::ptrdiff_t xk, int m, T* u) noexcept {
        constexpr int NL = detail::Vec<T, B>::lanes;
        constexpr int GM = NL / 2 > 0 ? NL / 2 : 1;
        const int ng = (n_inst_ + GM - 1) / GM;
        const int g = (n_inst_ + ng - 1) / ng;
        const Ticks t{xs, xr, xi, xk, m, u, ng};
        // g <= GM <= 4; each size is instantiated once.
        if constexpr (GM >= 4) {
            if (g == 4) return tick_groups<B, A, NIN, NV, 4>(t);
        }
        if constexpr (GM >= 3) {
            if (g == 3) return tick_groups<B, A, NIN, NV, 3>(t);
        }
        if constexpr (GM >= 2) {
            if (g == 2) return tick_groups<B, A, NIN, NV, 2>(t);
        }
        tick_groups<B, A, NIN, NV, 1>(t);
    }

    struct Ticks {
        const T* xs;
        std::ptrdiff_t xr, xi, xk;
        int m;
        T* u;
        int ng;
    };

    template <int B, Activation A, int NIN, int NV, int G>
    __attribute__((always_inline)) inline void tick_groups(const Ticks& t) noexcept {
        if constexpr (NV > 0) {
            if (t.ng > 1) {
                tick_pipelined<B, A, NIN, NV, G>(t);
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
                group<B, A, NIN, NV, G>(xk + r0 * t.xr, t.xr, t.xi, pk + r0 * ps, ps, uk + 2 * r0);
        }
    }

    // Software-pipelined ticks for ng >= 2 groups of G instances (NV known): the
    // output sigmoid of one group is computed right after the hidden sigmoids of
    // the next group (for the last group of a tick, of the first group of the next
    // tick). A group's chain hidden layer -> sums -> output is long and serial, and
    // the out-of-order window does not reach far enough to overlap consecutive
    // groups by itself (measured: groups ran almost one after the other); placing
    // independent work next to it in program order does.
    template <int B, Activation A, int NIN, int NV, int G>
    __attribute__((always_inline)) inline void tick_pipelined(const Ticks& t) noexcept {
        typedef typename detail::Vec<T, B>::type V;
        constexpr int KH = NV * G;
        V o;              // pending output pre-activations
        T* od = nullptr;  // and where their sigmoids go
        for (int k = 0; k < t.m; ++k) {
            const T* xk = t.xs + k * t.xk;
            T* uk = t.u + std::size_t(k) * urec_;
            const T* pk = k == 0 ? prev_ : uk - urec_ + 1;
            const std::ptrdiff_t ps = k == 0 ? 1 : 2;
            for (int g = 0, r0 = 0; g < t.ng; ++g, r0 += G) {
                V a[KH];
                hidden_pre<B, A, NIN, NV, G>(xk + r0 * t.xr, t.xr, t.xi, pk + r0 * ps, ps, a);
                sigmoid_batch<B, A, KH>(a);
                if (od) {
                    detail::sigmoid_k<T, B, A, 1, A == Activation::fast>(&o);
                    std::memcpy(od, &o, sizeof(V));
                }
                o = hidden_post<B, A, NV, G>(a);
                od = uk + 2 * r0;
            }
        }
        detail::sigmoid_k<T, B, A, 1, A == Activation::fast>(&o);
        std::memcpy(od, &o, sizeof(V));
    }

    // K sigmoids in interleaved passes of at most 4 vectors: measured as fast as
    // passes of 2 to 9 on the reference machine, with fewer spills.
    template <int B, Activation A, int K>
    static __attribute__((always_inline)) inline void sigmoid_batch(typename detail::Vec<T, B>::type* a) noexcept {
        constexpr int SB = 4;
        constexpr int NP = (K + SB - 1) / SB;           // passes
        constexpr int P0 = K / NP, PX = K % NP;         // balanced sizes: PX passes of P0 + 1
        int off = 0;
        _Pragma("GCC unroll 8") for (int q = 0; q < NP; ++q) {
            if (q < PX) {
                detail::sigmoid_k<T, B, A, P0 + 1, A == Activation::fast>(a + off);
                off += P0 + 1;
            } else {
                detail::sigmoid_k<T, B, A, P0, A == Activation::fast>(a + off);
                off += P0;
            }
        }
    }

    // Pre-activations of the G * NV hidden vectors of a group (a[v * G + j]).
    template <int B, Activation A, int NIN, int NV, int G>
    __attribute__((always_inline)) inline void hidden_pre(const T* xg, std::ptrdiff_t xr, std::ptrdiff_t xi,
                                                          const T* pg, std::ptrdiff_t ps,
                                                          typename detail::Vec<T, B>::type* a) const noexcept {
        typedef typename detail::Vec<T, B>::type V;
        constexpr int NL = detail::Vec<T, B>::lanes;
        constexpr std::size_t cs = std::size_t(NV * NL);
        const T* __restrict wc = wcol_[A == Activation::fast ? 1 : 0];
        V pb[G];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) pb[j] = detail::bcast<T, B>(pg + j * ps);
        _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v) {
            const T* w = wc + std::size_t(v) * NL;
            _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                V acc = load<V>(w);
                _Pragma("GCC unroll 8") for (int i = 0; i < NIN; ++i)
                    acc += load<V>(w + (1 + i) * cs) * detail::bcast<T, B>(xg + j * xr + i * xi);
                a[v * G + j] = acc + load<V>(w + (1 + NIN) * cs) * pb[j];
            }
        }
    }

    // Output pre-activations of a group from its hidden activations: one vector
    // [o_slip(0), o_pred(0), o_slip(1), ...].
    template <int B, Activation A, int NV, int G>
    __attribute__((always_inline)) inline typename detail::Vec<T, B>::type hidden_post(
        const typename detail::Vec<T, B>::type* a) const noexcept {
        typedef typename detail::Vec<T, B>::type V;
        constexpr int NL = detail::Vec<T, B>::lanes;
        constexpr std::size_t cs = std::size_t(NV * NL);
        const int nin = n_in_;
        const T* __restrict wc = wcol_[A == Activation::fast ? 1 : 0];
        const T* b2v = wc + (nin + 4) * cs;
        V s[NL];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
            s[2 * j] = load<V>(b2v);
            s[2 * j + 1] = load<V>(b2v + L);
        }
        _Pragma("GCC unroll 8") for (int v = 0; v < NV; ++v) {
            const T* w = wc + std::size_t(v) * NL;
            _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                s[2 * j] += load<V>(w + (2 + nin) * cs) * a[v * G + j];
                s[2 * j + 1] += load<V>(w + (3 + nin) * cs) * a[v * G + j];
            }
        }
        return detail::reduce_lanes<T, B, 2 * G>(s);
    }

    // One tick of G instances: feature i of instance j at xg[j * xr + i * xi],
    // feedback at pg[j * ps]; writes lanes [y_slip(0), y_pred(0), y_slip(1), ...]
    // (one vector) at ug. NIN, NV > 0: number of inputs and of hidden vectors known
    // at compile time; then all G * NV hidden sigmoids of the group go through one
    // interleaved pass (measured faster than a pass per hidden vector, and than one
    // pass over all groups, which spills too much).
    template <int B, Activation A, int NIN, int NV, int G>
    __attribute__((always_inline)) inline void group(const T* xg, std::ptrdiff_t xr, std::ptrdiff_t xi, const T* pg,
                                                     std::ptrdiff_t ps, T* ug) const noexcept {
        typedef typename detail::Vec<T, B>::type V;
        constexpr int NL = detail::Vec<T, B>::lanes;
        constexpr int KB = NV > 0 ? NV : 1;  // hidden vectors per sigmoid pass
        constexpr bool S = A == Activation::fast;  // pre-activations scaled by -log2(e)
        const int nin = NIN > 0 ? NIN : n_in_;
        const int nv = NV > 0 ? NV : hp_ / NL;
        const std::size_t cs = NV > 0 ? std::size_t(NV * NL) : std::size_t(hp_);  // column stride
        const T* __restrict wc = wcol_[S ? 1 : 0];
        const T* b2v = wc + (nin + 4) * cs;
        V pb[G], s0[G], s1[G];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
            pb[j] = detail::bcast<T, B>(pg + j * ps);
            s0[j] = load<V>(b2v);
            s1[j] = load<V>(b2v + L);
        }
        for (int v0 = 0; v0 < nv; v0 += KB) {
            V a[KB * G];
            _Pragma("GCC unroll 8") for (int v = 0; v < KB; ++v) {
                const T* w = wc + std::size_t(v0 + v) * NL;
                _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                    V acc = load<V>(w);
                    _Pragma("GCC unroll 8") for (int i = 0; i < nin; ++i)
                        acc += load<V>(w + (1 + i) * cs) * detail::bcast<T, B>(xg + j * xr + i * xi);
                    a[v * G + j] = acc + load<V>(w + (1 + nin) * cs) * pb[j];
                }
            }
            sigmoid_batch<B, A, KB * G>(a);
            _Pragma("GCC unroll 8") for (int v = 0; v < KB; ++v) {
                const T* w = wc + std::size_t(v0 + v) * NL;
                _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
                    s0[j] += load<V>(w + (2 + nin) * cs) * a[v * G + j];
                    s1[j] += load<V>(w + (3 + nin) * cs) * a[v * G + j];
                }
            }
        }
        V s[NL];
        _Pragma("GCC unroll 4") for (int j = 0; j < G; ++j) {
            s[2 * j] = s0[j];
            s[2 * j + 1] = s1[j];
        }
        V o = detail::reduce_lanes<T, B, 2 * G>(s);
        detail::sigmoid_k<T, B, A, 1, S>(&o);
        std::memcpy(ug, &o, sizeof(V));
    }

    template <typename V>
    static __attribute__((always_inline)) inline V load(const T* ptr) noexcept {
        V v;
        std::memcpy(&v, ptr, sizeof(V));
        return v;
    }

    int n_in_, n_h_, n_inst_, hp_ = 0;
    std::size_t urec_ = 0;
    Activation act_;
    SimdPath path_ = SimdPath::generic;
    std::unique_ptr<void, detail::AlignedFree> buf_;
    static constexpr int kChunk = 64;
    T* wcol_[2] = {nullptr, nullptr};
    T* xs_ = nullptr;
    T* xch_ = nullptr;
    T* ych_ = nullptr;
    T* prev_ = nullptr;
    T* w1_ = nullptr;
    T* b1_ = nullptr;
    T* w2_ = nullptr;
    T* b2_ = nullptr;
    T* mean_ = nullptr;
    T* gain_ = nullptr;
};

}  // namespace detector
}  // namespace tm_core

#undef TM_DETECTOR_SHUF
#pragma GCC diagnostic pop
