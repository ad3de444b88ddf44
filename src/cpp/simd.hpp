// The SIMD layer shared by every C++ kernel (SOS filters, slip detector and its
// training gradient, the pipeline): instruction-set detection and dispatch,
// vector types, loads and broadcasts, in-register transposes and reductions, and
// the exp and sigmoid approximations.
//
// Kernels are written once over GCC/Clang vector extensions (`Vec<T, B>::type`:
// B bytes, 16 or 32). Each hot entry point is compiled twice: for the x86-64
// baseline (SSE2; 32-byte operations split into two halves) and for AVX2+FMA
// (`TM_TARGET_AVX2`), and the variant is chosen at run time (`detect_isa`): the
// CPU's best, unless the process-wide baseline switch (`set_baseline`, or the
// environment variable TM_SIMD=baseline) holds every kernel to the baseline.
// A build with TM_NATIVE (-march=native) has a single variant tuned for the build
// host (`Isa::native`); off x86 there is one portable variant. The pattern:
//
//     template <int B> void kernel_impl(...);              // always inline
//     void kernel_base(...) { kernel_impl<simd::kBaseBytes>(...); }
//     #if TM_HAVE_DISPATCH
//     TM_TARGET_AVX2 void kernel_avx2(...) { kernel_impl<32>(...); }
//     #endif
//     ... if (isa == simd::Isa::avx2_fma) kernel_avx2(...); else kernel_base(...);
//
// simd::Dispatch<K> writes the two variants and the choice once for a kernel struct K
// (its body a static member template run<B>); the contact solver's kernels use it.
//
// Every function a variant inlines must be always-inline (TM_ALWAYS_INLINE), so
// that it is compiled for that variant's instruction set; the 32-byte x86
// builtins below are only ever expanded inside an AVX2 variant (or a native AVX2
// build). Vector types are passed between always-inline helpers only; the ABI
// note about 32-byte vector arguments (-Wpsabi) does not apply.
//
// Besides the layer (namespace tactile::simd) this header holds four helpers of
// the whole library in namespace tactile: DenormalGuard, best_time_ns, is_finite
// and AlignedBuffer.
#pragma once

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <string>
#include <type_traits>
#include <utility>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define TM_X86 1
#else
#define TM_X86 0
#endif

#define TM_ALWAYS_INLINE inline __attribute__((always_inline))

// TM_HAVE_DISPATCH: a separate AVX2+FMA variant exists (TM_TARGET_AVX2 marks its
// entry points). Without it TM_TARGET_AVX2 is empty and only the base variant is
// compiled.
#if TM_X86 && !defined(TM_NATIVE_BUILD)
#define TM_TARGET_AVX2 __attribute__((target("avx2,fma")))
#define TM_HAVE_DISPATCH 1
#else
#define TM_TARGET_AVX2
#define TM_HAVE_DISPATCH 0
#endif

// Lane permutation of two vectors of the same type (constant indices).
#define TM_SHUFFLE(a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wpsabi"

namespace tactile {
namespace simd {

// ---- instruction sets and run-time dispatch ----------------------------------

// The code variants a kernel can run: the portable baseline ("sse2" on x86-64,
// "generic" elsewhere), the AVX2+FMA variant of a portable x86 build, or the one
// variant of a -march=native build.
enum class Isa : int { baseline = 0, avx2_fma = 1, native = 2 };

// Vector width (bytes) of the base variant's kernels that choose their width:
// 16 for SSE2/NEON, 32 in a native build for an AVX2+FMA host (the 32-byte float
// exp relies on fused multiply-adds, see exp_neg_k).
#if defined(TM_NATIVE_BUILD) && defined(__AVX2__) && defined(__FMA__)
constexpr int kBaseBytes = 32;
#else
constexpr int kBaseBytes = 16;
#endif

inline bool cpu_has_avx2_fma() noexcept {
#if TM_X86
    static const bool has = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
    return has;
#else
    return false;
#endif
}

// The best variant this CPU and build offer (decided once).
inline Isa cpu_isa() noexcept {
#if defined(TM_NATIVE_BUILD)
    return Isa::native;
#elif TM_HAVE_DISPATCH
    return cpu_has_avx2_fma() ? Isa::avx2_fma : Isa::baseline;
#else
    return Isa::baseline;
#endif
}

// The process-wide baseline switch. While it is on, detect_isa() is the baseline:
// every kernel object built from then on (filters, detector nets, pipelines) and
// every call that dispatches per call (the contact solver, the training gradient)
// runs the baseline variant, so that machines with and without AVX2+FMA round
// alike. Objects built before keep their variant. Its first value comes from the
// environment variable TM_SIMD ("baseline": on; unset, empty or "auto": off), read
// when the switch is first consulted (the Python module consults it at import).
// A TM_NATIVE build has a single variant, which the switch leaves as it is.
namespace simd_detail {
inline bool baseline_requested_by_environment() noexcept {
    const char* v = std::getenv("TM_SIMD");
    return v != nullptr && std::strcmp(v, "baseline") == 0;
}
inline std::atomic<bool>& baseline_switch() noexcept {
    static std::atomic<bool> on{baseline_requested_by_environment()};
    return on;
}
}  // namespace simd_detail

inline bool baseline_forced() noexcept { return simd_detail::baseline_switch().load(std::memory_order_relaxed); }
// Turn the baseline switch on or off for the whole process. Switch between runs,
// not while another thread is inside a kernel (a contact solve would mix variants).
inline void set_baseline(bool on) noexcept { simd_detail::baseline_switch().store(on, std::memory_order_relaxed); }

// The variant the kernels use now: cpu_isa(), or the baseline while the switch is on.
inline Isa detect_isa() noexcept {
#if defined(TM_NATIVE_BUILD)
    return Isa::native;
#else
    return baseline_forced() ? Isa::baseline : cpu_isa();
#endif
}

// Whether a kernel can be told to run `isa` here now: the detected variant or the
// baseline (in a native build the baseline is the native code). While the baseline
// switch is on, AVX2+FMA cannot be chosen.
inline bool isa_supported(Isa isa) noexcept { return isa == Isa::baseline || isa == detect_isa(); }

// The one name of each variant, as tactile_mirror.simd_path() reports it.
inline const char* isa_name(Isa isa) noexcept {
    switch (isa) {
        case Isa::avx2_fma: return "avx2+fma";
        case Isa::native: return "native";
        default:
#if TM_X86
            return "sse2";
#else
            return "generic";
#endif
    }
}

// Parses a variant name: isa_name()'s names, plus "avx2" for "avx2+fma" and
// "generic" / "baseline" for the baseline on any platform. False if unknown.
inline bool parse_isa(const std::string& name, Isa* isa) noexcept {
    if (name == "avx2+fma" || name == "avx2") {
        *isa = Isa::avx2_fma;
    } else if (name == "native") {
        *isa = Isa::native;
    } else if (name == "generic" || name == "baseline" || name == isa_name(Isa::baseline)) {
        *isa = Isa::baseline;
    } else {
        return false;
    }
    return true;
}

// The pattern above as one helper: K is a kernel whose static member template
// K::run<B> is its body over B-byte vectors (always inline); base and avx2 are its two
// compiled variants and run() calls the AVX2+FMA one when told to (and it exists),
// else the baseline. The arguments are passed on to K::run as given.
template <class K>
struct Dispatch {
    template <class... A>
    static auto base(A... a) noexcept {
        return K::template run<kBaseBytes>(a...);
    }
#if TM_HAVE_DISPATCH
    template <class... A>
    TM_TARGET_AVX2 static auto avx2(A... a) noexcept {
        return K::template run<32>(a...);
    }
#endif
    template <class... A>
    static auto run(bool use_avx2, A... a) noexcept {
#if TM_HAVE_DISPATCH
        if (use_avx2) return avx2(a...);
#else
        (void)use_avx2;
#endif
        return base(a...);
    }
};

// ---- vector types ----------------------------------------------------------------

// Bit-level constants of T. clamp: the argument range of the exp and sigmoid
// approximations (exp(+-clamp) and the sigmoid of it are normal numbers).
template <typename T>
struct FloatTraits;
template <>
struct FloatTraits<float> {
    typedef std::int32_t iscalar;
    static constexpr float clamp = 80.0f;
    // 1.5 * 2^23 + 127: y + magic rounds y to an integer n (in the default
    // rounding mode) and leaves n + 127 in the low mantissa bits, so that those
    // bits shifted to the exponent field are 2^n.
    static constexpr float round_magic = 12583039.0f;
    static constexpr int mant = 23;
};
template <>
struct FloatTraits<double> {
    typedef std::int64_t iscalar;
    static constexpr double clamp = 600.0;
    static constexpr double round_magic = 6755399441056767.0;  // 1.5 * 2^52 + 1023, as above
    static constexpr int mant = 52;
};

// Vector of B bytes of T (16: one SSE2/NEON register, 32: one AVX register or
// two SSE2 registers), its integer twin and its lane count.
template <typename T, int B>
struct Vec;
#define TM_SIMD_VEC(T, IT, BYTES)                                           \
    template <>                                                             \
    struct Vec<T, BYTES> : FloatTraits<T> {                                 \
        typedef T type __attribute__((vector_size(BYTES)));                 \
        typedef IT itype __attribute__((vector_size(BYTES)));               \
        static constexpr int lanes = BYTES / int(sizeof(T));                \
    };
TM_SIMD_VEC(float, std::uint32_t, 16)
TM_SIMD_VEC(float, std::uint32_t, 32)
TM_SIMD_VEC(double, std::uint64_t, 16)
TM_SIMD_VEC(double, std::uint64_t, 32)
#undef TM_SIMD_VEC

// The 32-byte vector (4 doubles, 8 floats), the width of the filter kernels.
template <typename T>
using vec = typename Vec<T, 32>::type;

// ---- loads, stores, broadcasts -------------------------------------------------

template <typename T, int B = 32>
TM_ALWAYS_INLINE typename Vec<T, B>::type splat(T x) {
    typename Vec<T, B>::type v;
    for (int i = 0; i < Vec<T, B>::lanes; ++i) v[i] = x;
    return v;
}

// Unaligned load / store of a whole vector.
template <typename V, typename T>
TM_ALWAYS_INLINE V load(const T* p) {
    V v;
    std::memcpy(&v, p, sizeof(V));
    return v;
}
template <typename T, typename V>
TM_ALWAYS_INLINE void store(T* p, V v) {
    std::memcpy(p, &v, sizeof(V));
}

// The first `n` (< lanes) values at p, zeros after; built in registers (a
// buffer written lane by lane and read back as a vector stalls on store
// forwarding). Never reads past p[n - 1].
TM_ALWAYS_INLINE vec<double> load_partial(const double* p, std::size_t n) {
    switch (n) {
        case 1: return vec<double>{p[0], 0, 0, 0};
        case 2: return vec<double>{p[0], p[1], 0, 0};
        case 3: return vec<double>{p[0], p[1], p[2], 0};
        default: return vec<double>{0, 0, 0, 0};
    }
}
TM_ALWAYS_INLINE vec<float> load_partial(const float* p, std::size_t n) {
    switch (n) {
        case 1: return vec<float>{p[0], 0, 0, 0, 0, 0, 0, 0};
        case 2: return vec<float>{p[0], p[1], 0, 0, 0, 0, 0, 0};
        case 3: return vec<float>{p[0], p[1], p[2], 0, 0, 0, 0, 0};
        case 4: return vec<float>{p[0], p[1], p[2], p[3], 0, 0, 0, 0};
        case 5: return vec<float>{p[0], p[1], p[2], p[3], p[4], 0, 0, 0};
        case 6: return vec<float>{p[0], p[1], p[2], p[3], p[4], p[5], 0, 0};
        case 7: return vec<float>{p[0], p[1], p[2], p[3], p[4], p[5], p[6], 0};
        default: return vec<float>{0, 0, 0, 0, 0, 0, 0, 0};
    }
}

// One value from memory into every lane (a single broadcast load on x86).
template <typename T, int B>
TM_ALWAYS_INLINE typename Vec<T, B>::type bcast(const T* p) {
    return typename Vec<T, B>::type{} + *p;
}
#if TM_X86
template <>
TM_ALWAYS_INLINE Vec<float, 16>::type bcast<float, 16>(const float* p) {
    return (Vec<float, 16>::type)_mm_load1_ps(p);
}
template <>
TM_ALWAYS_INLINE Vec<double, 16>::type bcast<double, 16>(const double* p) {
    return (Vec<double, 16>::type)_mm_load1_pd(p);
}
// AVX variants only.
template <>
TM_ALWAYS_INLINE Vec<float, 32>::type bcast<float, 32>(const float* p) {
    return (Vec<float, 32>::type)__builtin_ia32_vbroadcastss256(p);
}
template <>
TM_ALWAYS_INLINE Vec<double, 32>::type bcast<double, 32>(const double* p) {
    return (Vec<double, 32>::type)__builtin_ia32_vbroadcastsd256(p);
}
#endif

// ---- transposes and reductions -------------------------------------------------

// In-place transpose of lanes x lanes values: afterwards lane k of v[q] is what
// lane q of v[k] was. Turns lanes samples of lanes channels (rows read from
// channel-major memory) into one vector per sample, and back.
TM_ALWAYS_INLINE void transpose(Vec<double, 16>::type* v) {
    typedef Vec<double, 16>::type V;
    const V a = TM_SHUFFLE(v[0], v[1], 0, 2), b = TM_SHUFFLE(v[0], v[1], 1, 3);
    v[0] = a;
    v[1] = b;
}
TM_ALWAYS_INLINE void transpose(Vec<double, 32>::type* v) {
    typedef Vec<double, 32>::type V;
    const V t0 = TM_SHUFFLE(v[0], v[1], 0, 4, 2, 6), t1 = TM_SHUFFLE(v[0], v[1], 1, 5, 3, 7);
    const V t2 = TM_SHUFFLE(v[2], v[3], 0, 4, 2, 6), t3 = TM_SHUFFLE(v[2], v[3], 1, 5, 3, 7);
    v[0] = TM_SHUFFLE(t0, t2, 0, 1, 4, 5);
    v[1] = TM_SHUFFLE(t1, t3, 0, 1, 4, 5);
    v[2] = TM_SHUFFLE(t0, t2, 2, 3, 6, 7);
    v[3] = TM_SHUFFLE(t1, t3, 2, 3, 6, 7);
}
TM_ALWAYS_INLINE void transpose(Vec<float, 16>::type* v) {
    typedef Vec<float, 16>::type V;
    const V t0 = TM_SHUFFLE(v[0], v[1], 0, 4, 1, 5), t1 = TM_SHUFFLE(v[0], v[1], 2, 6, 3, 7);
    const V t2 = TM_SHUFFLE(v[2], v[3], 0, 4, 1, 5), t3 = TM_SHUFFLE(v[2], v[3], 2, 6, 3, 7);
    v[0] = TM_SHUFFLE(t0, t2, 0, 1, 4, 5);
    v[1] = TM_SHUFFLE(t0, t2, 2, 3, 6, 7);
    v[2] = TM_SHUFFLE(t1, t3, 0, 1, 4, 5);
    v[3] = TM_SHUFFLE(t1, t3, 2, 3, 6, 7);
}
TM_ALWAYS_INLINE void transpose(Vec<float, 32>::type* v) {
    typedef Vec<float, 32>::type V;
    // 4 x 4 transposes inside the 128-bit halves, then the off-diagonal 4 x 4
    // blocks swap halves.
    V t[8], u[8];
    _Pragma("GCC unroll 4") for (int p = 0; p < 8; p += 2) {
        t[p] = TM_SHUFFLE(v[p], v[p + 1], 0, 8, 1, 9, 4, 12, 5, 13);
        t[p + 1] = TM_SHUFFLE(v[p], v[p + 1], 2, 10, 3, 11, 6, 14, 7, 15);
    }
    _Pragma("GCC unroll 2") for (int p = 0; p < 8; p += 4) {
        u[p] = TM_SHUFFLE(t[p], t[p + 2], 0, 1, 8, 9, 4, 5, 12, 13);
        u[p + 1] = TM_SHUFFLE(t[p], t[p + 2], 2, 3, 10, 11, 6, 7, 14, 15);
        u[p + 2] = TM_SHUFFLE(t[p + 1], t[p + 3], 0, 1, 8, 9, 4, 5, 12, 13);
        u[p + 3] = TM_SHUFFLE(t[p + 1], t[p + 3], 2, 3, 10, 11, 6, 7, 14, 15);
    }
    _Pragma("GCC unroll 4") for (int q = 0; q < 4; ++q) {
        v[q] = TM_SHUFFLE(u[q], u[q + 4], 0, 1, 2, 3, 8, 9, 10, 11);
        v[q + 4] = TM_SHUFFLE(u[q], u[q + 4], 4, 5, 6, 7, 12, 13, 14, 15);
    }
}

// Transpose-and-add: s[0..lanes-1] -> one vector whose lane k is the sum of the
// lanes of s[k]. log2(lanes) levels of two in-lane shuffles and one add per pair.
template <typename T, int B>
struct ReducePair;
template <>
struct ReducePair<float, 32> {
    typedef Vec<float, 32>::type V;
    static TM_ALWAYS_INLINE V pair(V x, V y, int lvl) {
        if (lvl < 2)  // [x0+x1, x2+x3, y0+y1, y2+y3 | ...]
            return TM_SHUFFLE(x, y, 0, 2, 8, 10, 4, 6, 12, 14) + TM_SHUFFLE(x, y, 1, 3, 9, 11, 5, 7, 13, 15);
        return TM_SHUFFLE(x, y, 0, 1, 2, 3, 8, 9, 10, 11) + TM_SHUFFLE(x, y, 4, 5, 6, 7, 12, 13, 14, 15);
    }
};
template <>
struct ReducePair<float, 16> {
    typedef Vec<float, 16>::type V;
    static TM_ALWAYS_INLINE V pair(V x, V y, int) {
        return TM_SHUFFLE(x, y, 0, 2, 4, 6) + TM_SHUFFLE(x, y, 1, 3, 5, 7);
    }
};
template <>
struct ReducePair<double, 32> {
    typedef Vec<double, 32>::type V;
    static TM_ALWAYS_INLINE V pair(V x, V y, int lvl) {
        if (lvl == 0) return TM_SHUFFLE(x, y, 0, 4, 2, 6) + TM_SHUFFLE(x, y, 1, 5, 3, 7);
        return TM_SHUFFLE(x, y, 0, 1, 4, 5) + TM_SHUFFLE(x, y, 2, 3, 6, 7);
    }
};
template <>
struct ReducePair<double, 16> {
    typedef Vec<double, 16>::type V;
    static TM_ALWAYS_INLINE V pair(V x, V y, int) { return TM_SHUFFLE(x, y, 0, 2) + TM_SHUFFLE(x, y, 1, 3); }
};

// One level of the transpose-and-add over the first M entries of s (the others
// are zero); all bounds are compile-time so that s stays in registers.
template <typename T, int B, int M, int Lvl>
TM_ALWAYS_INLINE void reduce_level(typename Vec<T, B>::type* s) {
    typedef typename Vec<T, B>::type V;
    _Pragma("GCC unroll 8") for (int k = 0; k < (M + 1) / 2; ++k) s[k] =
        ReducePair<T, B>::pair(s[2 * k], 2 * k + 1 < M ? s[2 * k + 1] : V{}, Lvl);
}

// s: the first N entries are live (overwritten); returns lane k = sum of the
// lanes of s[k] (zero for k >= N).
template <typename T, int B, int N>
TM_ALWAYS_INLINE typename Vec<T, B>::type reduce_lanes(typename Vec<T, B>::type* s) {
    constexpr int NL = Vec<T, B>::lanes;
    static_assert(N <= NL, "too many sums for one vector");
    reduce_level<T, B, N, 0>(s);
    if (NL >= 4) reduce_level<T, B, (N + 1) / 2, 1>(s);
    if (NL >= 8) reduce_level<T, B, (N + 3) / 4, 2>(s);
    return s[0];
}

// ---- element-wise helpers ------------------------------------------------------

template <typename T>
TM_ALWAYS_INLINE T clampv(T a, T lo, T hi) {
    return a < lo ? lo : (a > hi ? hi : a);
}

// Clamp to [-c, c] with min/max instructions (a NaN argument becomes -c).
template <typename V, typename T>
TM_ALWAYS_INLINE V clamp_sym(V a, T c) {
    const V lo = V{} - c, hi = V{} + c;
    a = a > lo ? a : lo;
    return a < hi ? a : hi;
}
#if TM_X86
TM_ALWAYS_INLINE Vec<float, 16>::type clamp_sym(Vec<float, 16>::type a, float c) {
    typedef Vec<float, 16>::type V;
    return (V)__builtin_ia32_minps(__builtin_ia32_maxps((__v4sf)a, (__v4sf)(V{} - c)), (__v4sf)(V{} + c));
}
TM_ALWAYS_INLINE Vec<double, 16>::type clamp_sym(Vec<double, 16>::type a, double c) {
    typedef Vec<double, 16>::type V;
    return (V)__builtin_ia32_minpd(__builtin_ia32_maxpd((__v2df)a, (__v2df)(V{} - c)), (__v2df)(V{} + c));
}
// AVX variants only.
TM_ALWAYS_INLINE Vec<float, 32>::type clamp_sym(Vec<float, 32>::type a, float c) {
    typedef Vec<float, 32>::type V;
    return (V)__builtin_ia32_minps256(__builtin_ia32_maxps256((__v8sf)a, (__v8sf)(V{} - c)), (__v8sf)(V{} + c));
}
TM_ALWAYS_INLINE Vec<double, 32>::type clamp_sym(Vec<double, 32>::type a, double c) {
    typedef Vec<double, 32>::type V;
    return (V)__builtin_ia32_minpd256(__builtin_ia32_maxpd256((__v4df)a, (__v4df)(V{} - c)),
                                      (__v4df)(V{} + c));
}
#endif

// sign(x) log(1 + |x ik|), cheaply (python: tactile_mirror.detector.bank.log_compress,
// the specification, which it matches bit for bit): with 1 + |x ik| = 2^E (1 + t),
// E and t read off the exponent and mantissa bits (both exact), log2(1 + t) is taken as
// t (1 + c (1 - t)), c = 11/32 (within 0.0056 of log(1 + |z|) after the ln 2).
// Every step is exact or one rounding; a caller compiled with fused multiply-adds
// would round differently (the bank's stage is compiled without them). E becomes a
// float by the magic-number trick: its bits or'ed into the mantissa of 2^mant (no
// integer-to-float conversion, which AVX2 lacks for 64-bit lanes).
template <typename T, int B>
TM_ALWAYS_INLINE typename Vec<T, B>::type log_compress(typename Vec<T, B>::type x, typename Vec<T, B>::type ik) {
    typedef Vec<T, B> VT;
    typedef typename VT::type V;
    typedef typename VT::itype IV;
    typedef typename std::remove_reference<decltype(IV{}[0])>::type IT;
    constexpr int M = VT::mant;
    constexpr IT bias = (IT(1) << (8 * int(sizeof(T)) - M - 2)) - 1;  // 127, 1023
    const IV sign = IV{} + (IT(1) << (8 * sizeof(T) - 1));
    const IV mant = IV{} + ((IT(1) << M) - 1);
    const IV one_bits = IV{} + (bias << M);              // the bits of 1.0
    const T magic = T(IT(1) << M);                        // 2^mant: its ulp is 1
    const IV magic_bits = (IV)(V{} + magic);
    const V z = x * ik;
    const V y = T(1) + (V)((IV)z & ~sign);                // >= 1: the sign bit is 0
    const IV b = (IV)y;
    // E = 2^mant + biased exponent - (2^mant + bias): exact (both are integers below 2^(mant+1))
    const V e = (V)((b >> M) | magic_bits) - (magic + T(bias));
    const V t = (V)((b & mant) | one_bits) - T(1);         // exact
    const V q = t * (T(1) + T(0.34375) * (T(1) - t));
    const V g = (e + q) * T(0.6931471805599453);
    return (V)((IV)g | ((IV)x & sign));
}

// 1/d for d >= 1. Exact division by default; for float on x86 the hardware
// reciprocal estimate refined by one Newton step (relative error < 2.5e-7 after
// rounding), which removes the divider from the fast path.
template <typename V>
TM_ALWAYS_INLINE V recip_fast(V d) {
    return 1 / d;
}
#if TM_X86
TM_ALWAYS_INLINE Vec<float, 16>::type recip_fast(Vec<float, 16>::type d) {
    typedef Vec<float, 16>::type V;
    const V r = (V)_mm_rcp_ps((__m128)d);
    return r + r * (1.0f - d * r);
}
// AVX variants only.
TM_ALWAYS_INLINE Vec<float, 32>::type recip_fast(Vec<float, 32>::type d) {
    typedef Vec<float, 32>::type V;
    const V r = (V)__builtin_ia32_rcpps256((__v8sf)d);
    return r + r * (1.0f - d * r);
}
#endif

// ---- exp and sigmoid -----------------------------------------------------------
//
// Accuracy::exact is accurate to a few ulp: exp with Cody-Waite range reduction
// (a two-constant split of ln2, except for float on the AVX2 variant, see
// exp_neg_k) and a near-minimax polynomial, degree 11 for double, 6 for float;
// the sigmoid then takes a true division. Accuracy::fast uses 2^y = 2^n * P(f),
// |f| <= 1/2 (degree 6 for double, relative error < 2e-9; degree 5 for float,
// < 1.1e-7) and, for the float sigmoid on x86, a reciprocal estimate with one
// Newton step. Both evaluate the polynomials by Estrin's scheme. Arguments are
// clamped to +-FloatTraits<T>::clamp (80 float, 600 double), so that no result is
// subnormal or infinite. Measured over 2e6 points in [-100, 100] against
// scipy.special.expit, the sigmoid's |error| is <= 1.7e-16 exact double,
// <= 4.7e-10 fast double, <= 8.9e-8 exact float, <= 1.9e-7 fast float (1.4e-7 on
// the AVX2 variant). exp's relative error over the clamp range (measured, 2e5
// points, against long double; tests/cpp/test_simd.cpp): <= 3.9e-16 exact double,
// <= 1.9e-9 fast double, <= 1.7e-7 exact float (3.3e-7 on the AVX2 variant),
// <= 3.9e-6 fast float (growing with |x|: the rounding of x log2(e) to float;
// <= 1.1e-6 for |x| < 20).

enum class Accuracy : int { exact = 0, fast = 1 };

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
TM_ALWAYS_INLINE T coef(const double* c, int k) {
    return T(k > N ? 0.0 : (Neg && (k & 1) ? -c[k] : c[k]));
}

template <typename T, int N, bool Neg, typename V>
TM_ALWAYS_INLINE V estrin(const double* c, V x) {
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

// Scalar sigmoids (the detector's scalar reference path).
template <typename T>
inline T sigmoid_exact_scalar(T a) {
    a = clampv<T>(a, -FloatTraits<T>::clamp, FloatTraits<T>::clamp);
    return T(1) / (T(1) + std::exp(-a));
}

template <typename T>
inline T sigmoid_fast_scalar(T a) {
    typedef typename std::make_unsigned<typename FloatTraits<T>::iscalar>::type I;  // modular shifts
    a = clampv<T>(a, -FloatTraits<T>::clamp, FloatTraits<T>::clamp);
    const T y = a * T(-1.4426950408889634);
    const T t = y + FloatTraits<T>::round_magic;  // round to nearest integer (no -ffast-math)
    I tb;
    std::memcpy(&tb, &t, sizeof tb);
    const T f = y - (t - FloatTraits<T>::round_magic);
    const T p = estrin<T, FastPoly<T>::degree, false>(FastPoly<T>::c, f);
    const I eb = static_cast<I>(tb << FloatTraits<T>::mant);
    T scale;
    std::memcpy(&scale, &eb, sizeof scale);
    return T(1) / (T(1) + p * scale);
}

// exp(-a) (PlusOne: 1 + exp(-a), with the add fused into the last multiply) of K
// independent vectors into e, computed stage by stage across the K vectors so
// that their dependency chains interleave in the instruction stream (the chain is
// long, and the out-of-order window holds only a few of them at a time). a is
// clamped in place to +-clamp. Scaled (fast only): the argument is already
// y = -a log2(e) (a kernel can fold the factor into its weights), which saves a
// multiply; its clamp is then +-clamp * log2(e).
#define TM_K _Pragma("GCC unroll 16") for (int u = 0; u < K; ++u)
template <typename T, int B, Accuracy A, int K, bool Scaled = false, bool PlusOne = false>
TM_ALWAYS_INLINE void exp_neg_k(typename Vec<T, B>::type* a, typename Vec<T, B>::type* e) {
    typedef Vec<T, B> VT;
    typedef typename VT::type V;
    typedef typename VT::itype IV;
    static_assert(!Scaled || A == Accuracy::fast, "scaled arguments are for the fast approximation");
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
    if (A == Accuracy::exact) {
        // exp(-a) to about one ulp: -a = n ln2 - s, |s| <= ln2/2 (Cody-Waite split
        // of ln2, s = a + n ln2), exp(-s) by the polynomial.
        if (sizeof(T) == 8) {
            TM_K y[u] = t[u] * T(0.693147180369123816490) + a[u];
            TM_K y[u] = t[u] * T(1.90821492927058770002e-10) + y[u];
        } else if (B == 32) {
            // Float on the FMA path: one fused step with ln2 rounded to float. Its
            // error, |n| * 1.9e-9 relative in exp(-a), exceeds a float ulp only for
            // |n| > 30, where the sigmoid is below 1e-9 or rounds to 1: there the
            // relative error grows from 2.3e-7 to 3.3e-7 (measured); the absolute
            // error bound of the sigmoid (8.9e-8) does not change. One multiply-add
            // less is 7% of the detector's float tick. (Needs the multiply-add to
            // be fused, as in the -O2 build: unfused, exp's error grows to ~5e-6.)
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
        if (PlusOne)
            e[u] = p[u] * scale + T(1);
        else
            e[u] = p[u] * scale;
    }
}

// K sigmoids in place: a <- 1 / (1 + exp(-a)), interleaved as exp_neg_k.
template <typename T, int B, Accuracy A, int K, bool Scaled = false>
TM_ALWAYS_INLINE void sigmoid_k(typename Vec<T, B>::type* a) {
    typename Vec<T, B>::type t[K];
    exp_neg_k<T, B, A, K, Scaled, true>(a, t);
    if (A == Accuracy::exact) {
        TM_K a[u] = T(1) / t[u];
    } else {
        TM_K a[u] = recip_fast(t[u]);
    }
}

// K exponentials in place: x <- exp(x), x clamped to +-clamp.
template <typename T, int B, Accuracy A, int K>
TM_ALWAYS_INLINE void exp_k(typename Vec<T, B>::type* x) {
    typename Vec<T, B>::type a[K];
    TM_K a[u] = -x[u];
    exp_neg_k<T, B, A, K>(a, x);
}
#undef TM_K

// The sigmoid of one vector with the detector kernel's arithmetic (for the fast
// accuracy the kernel's pre-activation is already scaled by -log2(e); here one
// multiply).
template <typename T, int B, Accuracy A>
TM_ALWAYS_INLINE typename Vec<T, B>::type sigmoid_vec(typename Vec<T, B>::type a) {
    if (A == Accuracy::fast) {
        a = a * T(-1.4426950408889634);
        sigmoid_k<T, B, Accuracy::fast, 1, true>(&a);
    } else {
        sigmoid_k<T, B, A, 1>(&a);
    }
    return a;
}

// The sigmoid (Exp = false) or exp (Exp = true) of n values, vector by vector
// (the tail in a zero-padded vector); in and out may be the same array. (Loops,
// not a lambda: a lambda would not inherit an AVX2 variant's target.)
template <typename T, int B, Accuracy A, bool Exp>
TM_ALWAYS_INLINE void map_vec(typename Vec<T, B>::type* v) noexcept {
    if (Exp)
        exp_k<T, B, A, 1>(v);
    else
        *v = sigmoid_vec<T, B, A>(*v);
}

template <typename T, int B, Accuracy A, bool Exp>
TM_ALWAYS_INLINE void map_array(const T* in, T* out, std::size_t n) noexcept {
    typedef typename Vec<T, B>::type V;
    constexpr int NL = Vec<T, B>::lanes;
    std::size_t i = 0;
    for (; i + NL <= n; i += NL) {
        V v = load<V>(in + i);
        map_vec<T, B, A, Exp>(&v);
        store(out + i, v);
    }
    if (i < n) {
        V v = V{};
        for (std::size_t k = i; k < n; ++k) v[k - i] = in[k];
        map_vec<T, B, A, Exp>(&v);
        for (std::size_t k = i; k < n; ++k) out[k] = v[k - i];
    }
}

template <typename T, int B, Accuracy A>
TM_ALWAYS_INLINE void sigmoid_array_impl(const T* in, T* out, std::size_t n) noexcept {
    map_array<T, B, A, false>(in, out, n);
}

template <typename T, Accuracy A, bool Exp>
__attribute__((noinline)) void map_array_base(const T* in, T* out, std::size_t n) noexcept {
    map_array<T, kBaseBytes, A, Exp>(in, out, n);
}
#if TM_HAVE_DISPATCH
template <typename T, Accuracy A, bool Exp>
TM_TARGET_AVX2 __attribute__((noinline)) void map_array_avx2(const T* in, T* out, std::size_t n) noexcept {
    map_array<T, 32, A, Exp>(in, out, n);
}
#endif

// map_array with the given accuracy and variant; a variant this CPU lacks runs the
// baseline.
template <typename T, bool Exp>
inline void map_array_dispatch(const T* in, T* out, std::size_t n, Accuracy acc, Isa isa) noexcept {
#if TM_HAVE_DISPATCH
    if (isa == Isa::avx2_fma && isa_supported(isa)) {
        if (acc == Accuracy::exact)
            map_array_avx2<T, Accuracy::exact, Exp>(in, out, n);
        else
            map_array_avx2<T, Accuracy::fast, Exp>(in, out, n);
        return;
    }
#else
    (void)isa;
#endif
    if (acc == Accuracy::exact)
        map_array_base<T, Accuracy::exact, Exp>(in, out, n);
    else
        map_array_base<T, Accuracy::fast, Exp>(in, out, n);
}

// The detector kernel's sigmoid on n values with the given accuracy and variant
// (for measuring the approximation error).
template <typename T>
inline void sigmoid_array(const T* in, T* out, std::size_t n, Accuracy acc, Isa isa) noexcept {
    map_array_dispatch<T, false>(in, out, n, acc, isa);
}

// exp on n values, likewise.
template <typename T>
inline void exp_array(const T* in, T* out, std::size_t n, Accuracy acc, Isa isa) noexcept {
    map_array_dispatch<T, true>(in, out, n, acc, isa);
}

}  // namespace simd

// ---- library helpers ----------------------------------------------------------------

// Flush-to-zero / denormals-are-zero for the calling thread while in scope,
// restored on exit. Filter states decaying towards zero otherwise enter the
// subnormal range (after ~60 s in float64, ~6 s in float32 at kHz rates) and
// every operation on them costs 60-80x more.
//
// Setting MXCSR costs ~10 ns per call pair, so the guard only writes it when the
// bits are not already set: a real-time thread that enables FTZ once (a
// DenormalGuard around its loop) pays ~1 ns per kernel call.
class DenormalGuard {
public:
    DenormalGuard() noexcept {
#if TM_X86
        saved_ = _mm_getcsr();
        if ((saved_ & kBits) != kBits) {
            _mm_setcsr(saved_ | kBits);
            changed_ = true;
        }
#elif defined(__aarch64__)
        __asm__ __volatile__("mrs %0, fpcr" : "=r"(saved_));
        const std::uint64_t fz = std::uint64_t(1) << 24;
        if (!(saved_ & fz)) {
            std::uint64_t v = saved_ | fz;
            __asm__ __volatile__("msr fpcr, %0" : : "r"(v));
            changed_ = true;
        }
#endif
    }
    ~DenormalGuard() {
        if (!changed_) return;
#if TM_X86
        _mm_setcsr(saved_);
#elif defined(__aarch64__)
        __asm__ __volatile__("msr fpcr, %0" : : "r"(saved_));
#endif
    }
    DenormalGuard(const DenormalGuard&) = delete;
    DenormalGuard& operator=(const DenormalGuard&) = delete;

private:
#if TM_X86
    static constexpr unsigned int kBits = 0x8040u;  // FTZ (bit 15) | DAZ (bit 6)
    unsigned int saved_ = 0;
#else
    std::uint64_t saved_ = 0;
#endif
    bool changed_ = false;
};

// Mean time of one call(i) in ns over i = 0 .. n_iter - 1, the best of `repeats` runs,
// measured under flush-to-zero, as every real-time caller runs the kernels: a filter
// state decaying toward zero (a channel that reads exactly 0) otherwise times subnormal
// arithmetic, not the kernel (measured, filter-bank net after a block run: 545 ns a
// tick, not 345). The kernels' time_step_ns() are this around their step().
template <typename F>
double best_time_ns(long n_iter, int repeats, F&& call) {
    DenormalGuard ftz;
    double best = std::numeric_limits<double>::infinity();
    for (int rep = 0; rep < repeats; ++rep) {
        const auto t0 = std::chrono::steady_clock::now();
        for (long i = 0; i < n_iter; ++i) call(i);
        const auto t1 = std::chrono::steady_clock::now();
        const double ns = std::chrono::duration<double, std::nano>(t1 - t0).count() / double(n_iter);
        if (ns < best) best = ns;
    }
    return best;
}

// x is finite (not NaN, not +-Inf), written so that -ffast-math cannot fold it.
template <typename T>
TM_ALWAYS_INLINE bool is_finite(T x) {
    T d = x - x;  // 0 for finite x, NaN otherwise
    return d == d;
}

// Owning, 64-byte aligned buffer; allocated at construction only.
template <typename T>
class AlignedBuffer {
public:
    AlignedBuffer() = default;
    explicit AlignedBuffer(std::size_t n) { resize(n); }
    ~AlignedBuffer() { std::free(ptr_); }
    AlignedBuffer(const AlignedBuffer& o) { copy_from(o); }
    AlignedBuffer& operator=(const AlignedBuffer& o) {
        if (this != &o) copy_from(o);
        return *this;
    }
    AlignedBuffer(AlignedBuffer&& o) noexcept : ptr_(o.ptr_), n_(o.n_) {
        o.ptr_ = nullptr;
        o.n_ = 0;
    }
    AlignedBuffer& operator=(AlignedBuffer&& o) noexcept {
        std::swap(ptr_, o.ptr_);
        std::swap(n_, o.n_);
        return *this;
    }
    void resize(std::size_t n) {
        std::free(ptr_);
        ptr_ = nullptr;
        n_ = n;
        if (n) {
            std::size_t bytes = ((n * sizeof(T) + 63) / 64) * 64;
            ptr_ = static_cast<T*>(std::aligned_alloc(64, bytes));
            if (!ptr_) throw std::bad_alloc();
            std::memset(static_cast<void*>(ptr_), 0, bytes);
        }
    }
    T* data() noexcept { return ptr_; }
    const T* data() const noexcept { return ptr_; }
    std::size_t size() const noexcept { return n_; }
    T& operator[](std::size_t i) noexcept { return ptr_[i]; }
    const T& operator[](std::size_t i) const noexcept { return ptr_[i]; }

private:
    void copy_from(const AlignedBuffer& o) {
        resize(o.n_);
        if (o.n_) std::memcpy(static_cast<void*>(ptr_), o.ptr_, o.n_ * sizeof(T));
    }
    T* ptr_ = nullptr;
    std::size_t n_ = 0;
};

}  // namespace tactile

#pragma GCC diagnostic pop
