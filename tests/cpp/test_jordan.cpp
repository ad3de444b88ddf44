// Stand-alone test of the Jordan MLP kernel (jordan_mlp.hpp) and the filter-bank
// front end (detector_bank.hpp), built with AddressSanitizer (see
// tests/test_cpp_kernels.py): for float and double, every code variant the CPU runs,
// both activations, 4 / 8 / 17 inputs (the unrolled sizes, with and without the block
// path's projections) and 5 inputs (the generic path), 1 to 13 instances (groups
// padded with ghost instances), a block run over several chunks must give the bits of
// the same ticks stepped one at a time, and agree with the scalar step_one(). The
// sanitizer checks every buffer the block path indexes. Also: step_feature_major's
// ghost lanes change nothing, and a bank with the pad's mean and knees. No input file.
//
// Built from three translation units: this one (main), and test_jordan_float.cpp
// and test_jordan_double.cpp, which instantiate the checks in jordan_checks.hpp.
#include <cstdio>

#include "check.hpp"
#include "jordan_checks.hpp"

using namespace jordan_test;

int main() {
    Rng g{12345};
    const simd::Isa isas[2] = {simd::Isa::baseline, simd::Isa::avx2_fma};
    int variants = 0;
    for (simd::Isa isa : isas) {
        if (!simd::isa_supported(isa)) continue;
        ++variants;
        for (int nin : {4, 5, 8, 17})
            for (int R : {1, 2, 3, 6, 7, 13})
                for (det::Activation act : {det::Activation::exact, det::Activation::fast}) {
                    check_mlp<float>(nin, R, act, isa, g);
                    check_mlp<double>(nin, R, act, isa, g);
                }
        for (int nin : {5, 17})
            for (int R : {1, 6, 7, 9, 13}) {
                check_feature_major<float>(nin, R, isa, g);
                check_feature_major<double>(nin, R, isa, g);
            }
        for (int R : {1, 6, 9})
            for (int n : {7, 65}) {
                check_bank<float>(R, isa, g, 4, 2, n, false, true);
                check_bank<double>(R, isa, g, 4, 2, n, false, true);
            }
        for (int R : {1, 6, 7, 9})
            for (int lp_abs : {0x34, 0x42, 0x21})
                for (int n : {3, 7, 65, 150})
                    for (bool time_major : {false, true}) {
                        if (time_major && n != 65) continue;
                        check_bank<float>(R, isa, g, lp_abs >> 4, lp_abs & 15, n, time_major);
                        check_bank<double>(R, isa, g, lp_abs >> 4, lp_abs & 15, n, time_major);
                    }
    }
    std::printf("%d code variants\nok: %d failures\n", variants, failures);
    return failures ? 1 : 0;
}
