// Portable SIMD support shared by the kernels.
//
// Kernels are written once over GCC/Clang vector extensions (`vec<T>`: 32 bytes, 4
// doubles or 8 floats). Each hot entry point is compiled twice: for the x86-64
// baseline (the vector ops split into SSE2 halves) and for AVX2+FMA, and the
// variant is chosen once at run time with `__builtin_cpu_supports`. A build with
// TM_NATIVE (-march=native) has a single variant tuned for the build host.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <new>
#include <utility>

#if defined(__x86_64__) || defined(__i386__)
#include <xmmintrin.h>
#define TM_X86 1
#else
#define TM_X86 0
#endif

#define TM_ALWAYS_INLINE inline __attribute__((always_inline))

#if TM_X86 && !defined(TM_NATIVE_BUILD)
#define TM_TARGET_AVX2 __attribute__((target("avx2,fma")))
#define TM_HAVE_DISPATCH 1
#else
#define TM_TARGET_AVX2
#define TM_HAVE_DISPATCH 0
#endif

namespace tactile {

// 32-byte vectors: one AVX register, two SSE registers on the baseline.
template <typename T>
struct vec_of;
template <>
struct vec_of<double> {
    typedef double type __attribute__((vector_size(32)));
    static constexpr int lanes = 4;
};
template <>
struct vec_of<float> {
    typedef float type __attribute__((vector_size(32)));
    static constexpr int lanes = 8;
};
template <typename T>
using vec = typename vec_of<T>::type;

template <typename T>
TM_ALWAYS_INLINE vec<T> splat(T x) {
    vec<T> v;
    for (int i = 0; i < vec_of<T>::lanes; ++i) v[i] = x;
    return v;
}

#define TM_SHUFFLE(a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)

// In-register transpose of a W x W block: r[i][j] -> o[j][i]. Turns W samples of
// W channels (rows read from channel-major memory) into W vectors of W channels
// (one per sample), and back: the kernels' only data reshuffling.
TM_ALWAYS_INLINE void transpose(const vec<double>* r, vec<double>* o) {
    using V = vec<double>;
    V t0 = TM_SHUFFLE(r[0], r[1], 0, 4, 2, 6);
    V t1 = TM_SHUFFLE(r[0], r[1], 1, 5, 3, 7);
    V t2 = TM_SHUFFLE(r[2], r[3], 0, 4, 2, 6);
    V t3 = TM_SHUFFLE(r[2], r[3], 1, 5, 3, 7);
    o[0] = TM_SHUFFLE(t0, t2, 0, 1, 4, 5);
    o[1] = TM_SHUFFLE(t1, t3, 0, 1, 4, 5);
    o[2] = TM_SHUFFLE(t0, t2, 2, 3, 6, 7);
    o[3] = TM_SHUFFLE(t1, t3, 2, 3, 6, 7);
}

TM_ALWAYS_INLINE void transpose(const vec<float>* r, vec<float>* o) {
    using V = vec<float>;
    V a[8], b[8];
    for (int i = 0; i < 8; i += 2) {
        a[i] = TM_SHUFFLE(r[i], r[i + 1], 0, 8, 1, 9, 4, 12, 5, 13);
        a[i + 1] = TM_SHUFFLE(r[i], r[i + 1], 2, 10, 3, 11, 6, 14, 7, 15);
    }
    for (int i = 0; i < 8; i += 4) {
        b[i] = TM_SHUFFLE(a[i], a[i + 2], 0, 1, 8, 9, 4, 5, 12, 13);
        b[i + 1] = TM_SHUFFLE(a[i], a[i + 2], 2, 3, 10, 11, 6, 7, 14, 15);
        b[i + 2] = TM_SHUFFLE(a[i + 1], a[i + 3], 0, 1, 8, 9, 4, 5, 12, 13);
        b[i + 3] = TM_SHUFFLE(a[i + 1], a[i + 3], 2, 3, 10, 11, 6, 7, 14, 15);
    }
    for (int i = 0; i < 4; ++i) {
        o[i] = TM_SHUFFLE(b[i], b[i + 4], 0, 1, 2, 3, 8, 9, 10, 11);
        o[i + 4] = TM_SHUFFLE(b[i], b[i + 4], 4, 5, 6, 7, 12, 13, 14, 15);
    }
}

template <typename T>
TM_ALWAYS_INLINE vec<T> load_unaligned(const T* p) {
    vec<T> v;
    std::memcpy(&v, p, sizeof(v));
    return v;
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

template <typename T>
TM_ALWAYS_INLINE void store_unaligned(T* p, vec<T> v) {
    std::memcpy(p, &v, sizeof(v));
}

// Which instruction set the dispatched kernels use.
enum class Isa : int { baseline = 0, avx2_fma = 1, native = 2 };

inline Isa detect_isa() {
#if defined(TM_NATIVE_BUILD)
    return Isa::native;
#elif TM_HAVE_DISPATCH
    static const Isa isa = (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))
                               ? Isa::avx2_fma
                               : Isa::baseline;
    return isa;
#else
    return Isa::baseline;
#endif
}

inline const char* isa_name(Isa isa) {
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
