// Stand-alone test of the SIMD layer (simd.hpp), built at -O2 with AddressSanitizer
// and UBSan (see tests/test_cpp_kernels.py): the variant names, the transposes and
// lane reductions of every vector type against scalar loops, and the error of
// exp and of the sigmoid against long-double references, on the baseline variant
// and (where the CPU has it) the AVX2+FMA variant. No input file.
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "simd.hpp"
#include "check.hpp"

namespace simd = tactile::simd;

// ---- transposes and reductions, per vector type ----------------------------------

template <typename T, int B>
TM_ALWAYS_INLINE int check_shuffles() {
    typedef typename simd::Vec<T, B>::type V;
    constexpr int NL = simd::Vec<T, B>::lanes;
    int bad = 0;
    V v[NL];
    for (int q = 0; q < NL; ++q)
        for (int k = 0; k < NL; ++k) v[q][k] = T(100 * q + k);
    simd::transpose(v);
    for (int q = 0; q < NL; ++q)
        for (int k = 0; k < NL; ++k) bad += v[q][k] != T(100 * k + q);
    // Integer-valued lanes: every summation order gives the exact sum.
    V s[NL];
    for (int q = 0; q < NL; ++q)
        for (int k = 0; k < NL; ++k) s[q][k] = T((q + 1) * (k + 3) % 17);
    T want[NL];
    for (int q = 0; q < NL; ++q) {
        want[q] = 0;
        for (int k = 0; k < NL; ++k) want[q] += s[q][k];
    }
    V r = simd::reduce_lanes<T, B, NL>(s);
    for (int q = 0; q < NL; ++q) bad += r[q] != want[q];
    // Fewer live sums than lanes: the other lanes come out zero.
    for (int q = 0; q < NL; ++q)
        for (int k = 0; k < NL; ++k) s[q][k] = T((q + 1) * (k + 3) % 17);
    r = simd::reduce_lanes<T, B, 1>(s);
    bad += r[0] != want[0];
    for (int q = 1; q < NL; ++q) bad += r[q] != T(0);
    // Broadcast, clamp.
    const T x = T(2.5);
    const V b = simd::bcast<T, B>(&x);
    const V c = simd::clamp_sym(b * T(100), T(7));
    for (int k = 0; k < NL; ++k) bad += b[k] != x || c[k] != T(7);
    return bad;
}

int shuffles_base() {
    return check_shuffles<float, 16>() + check_shuffles<double, 16>() + check_shuffles<float, simd::kBaseBytes>() +
           check_shuffles<double, simd::kBaseBytes>();
}
#if TM_HAVE_DISPATCH
TM_TARGET_AVX2 __attribute__((noinline)) int shuffles_avx2() {
    return check_shuffles<float, 32>() + check_shuffles<double, 32>();
}
#endif

// ---- exp and sigmoid errors --------------------------------------------------------

// Largest relative error of exp and absolute error of the sigmoid over [-lim, lim].
template <typename T>
void errors(simd::Accuracy acc, simd::Isa isa, double lim, double* e_exp, double* e_sig, bool* normal) {
    const std::size_t n = 200001;  // odd: the tail vector is partial
    std::vector<T> x(n), y(n), s(n);
    for (std::size_t i = 0; i < n; ++i) x[i] = T(-lim + 2 * lim * double(i) / double(n - 1));
    simd::exp_array<T>(x.data(), y.data(), n, acc, isa);
    simd::sigmoid_array<T>(x.data(), s.data(), n, acc, isa);
    *e_exp = *e_sig = 0;
    *normal = true;
    for (std::size_t i = 0; i < n; ++i) {
        const long double xl = x[i];
        const long double re = std::exp(xl), rs = 1.0L / (1.0L + std::exp(-xl));
        *e_exp = std::fmax(*e_exp, double(std::fabs((y[i] - re) / re)));
        *e_sig = std::fmax(*e_sig, double(std::fabs(s[i] - rs)));
        *normal &= std::isnormal(y[i]) && (s[i] == 0 || std::isnormal(s[i]));
    }
}

template <typename T>
void check_accuracy(simd::Isa isa) {
    const char* tn = sizeof(T) == 4 ? "float" : "double";
    // exp: within the clamp (float exp(80) ~ 5.5e34, double exp(600) ~ 3.8e260).
    // Bounds: the errors documented in simd.hpp (measured, -O2 build); the
    // sigmoid's are also tested through tests/test_detector.py. (Float exact on
    // the AVX2 variant needs the fused multiply-add of an -O2 build.)
    struct Case {
        simd::Accuracy acc;
        double lim, exp_bound, sig_bound;
    };
    const Case exact = sizeof(T) == 4 ? Case{simd::Accuracy::exact, 80.0, 4e-7, 1.2e-7}
                                      : Case{simd::Accuracy::exact, 600.0, 5e-16, 1e-15};
    const Case fast = sizeof(T) == 4 ? Case{simd::Accuracy::fast, 80.0, 5e-6, 2.5e-7}
                                     : Case{simd::Accuracy::fast, 600.0, 3e-9, 5e-10};
    const Case all[2] = {exact, fast};
    for (const Case& c : all) {
        double ee, es;
        bool normal;
        errors<T>(c.acc, isa, c.lim, &ee, &es, &normal);
        const char* an = c.acc == simd::Accuracy::exact ? "exact" : "fast";
        std::printf("%s %s %s: exp rel err %.3g, sigmoid abs err %.3g\n", simd::isa_name(isa), tn, an, ee, es);
        CHECK(ee <= c.exp_bound, "%s %s %s exp error %g > %g", simd::isa_name(isa), tn, an, ee, c.exp_bound);
        CHECK(es <= c.sig_bound, "%s %s %s sigmoid error %g > %g", simd::isa_name(isa), tn, an, es, c.sig_bound);
        CHECK(normal, "%s %s %s: a subnormal or non-finite result", simd::isa_name(isa), tn, an);
        // Beyond the clamp: exp(+-clamp), finite and normal.
        T big[3] = {T(-1e6), T(1e6), T(NAN)}, out[3];
        simd::exp_array<T>(big, out, 3, c.acc, isa);
        CHECK(std::isnormal(out[0]) && std::isnormal(out[1]) && out[0] < out[1],
              "%s %s %s: exp beyond the clamp gives %g, %g", simd::isa_name(isa), tn, an, double(out[0]),
              double(out[1]));
    }
}

int main() {
    // Names: one per variant, and parse_isa inverts isa_name.
    const simd::Isa all[3] = {simd::Isa::baseline, simd::Isa::avx2_fma, simd::Isa::native};
    for (simd::Isa isa : all) {
        simd::Isa back;
        CHECK(simd::parse_isa(simd::isa_name(isa), &back) && back == isa, "parse_isa(isa_name(%d))", int(isa));
    }
    simd::Isa g;
    CHECK(simd::parse_isa("generic", &g) && g == simd::Isa::baseline, "'generic' is the baseline");
    CHECK(!simd::parse_isa("neon", &g), "'neon' is not a variant");
    CHECK(simd::isa_supported(simd::Isa::baseline), "the baseline always runs");
    CHECK(simd::isa_supported(simd::detect_isa()), "the detected variant runs");
    std::printf("detected variant: %s\n", simd::isa_name(simd::detect_isa()));
    // The baseline switch: while on, the baseline is what runs and AVX2+FMA cannot be chosen.
    const simd::Isa detected = simd::detect_isa();
    const bool forced = simd::baseline_forced();  // (TM_SIMD=baseline in the environment)
    simd::set_baseline(true);
#if !defined(TM_NATIVE_BUILD)
    CHECK(simd::detect_isa() == simd::Isa::baseline, "the baseline switch holds detect_isa to the baseline");
    CHECK(!simd::isa_supported(simd::Isa::avx2_fma), "AVX2+FMA cannot be chosen under the baseline switch");
#endif
    simd::set_baseline(false);
    CHECK(simd::detect_isa() == simd::cpu_isa(), "the switch off gives the CPU's best variant");
    simd::set_baseline(forced);
    CHECK(simd::detect_isa() == detected, "the switch restored");

    CHECK(shuffles_base() == 0, "transpose / reduce_lanes / bcast / clamp_sym, baseline variant");
    check_accuracy<float>(simd::Isa::baseline);
    check_accuracy<double>(simd::Isa::baseline);
#if TM_HAVE_DISPATCH
    if (simd::isa_supported(simd::Isa::avx2_fma)) {
        CHECK(shuffles_avx2() == 0, "transpose / reduce_lanes / bcast / clamp_sym, AVX2 variant");
        check_accuracy<float>(simd::Isa::avx2_fma);
        check_accuracy<double>(simd::Isa::avx2_fma);
    } else {
        std::printf("no AVX2+FMA on this CPU: baseline only\n");
    }
#endif
    std::printf("ok: %d failures\n", failures);
    return failures ? 1 : 0;
}
