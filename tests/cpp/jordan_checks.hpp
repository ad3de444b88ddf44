// The checks of tests/cpp/test_jordan.cpp (see there), as templates defined here
// and instantiated, per value type, in test_jordan_float.cpp and
// test_jordan_double.cpp: three translation units, each of which the sanitizer
// build compiles in a fraction of the time of one holding every kernel (and the
// two can be compiled at once). test_jordan.cpp includes this header for main()
// only; the extern declarations at the end keep it from instantiating the checks.
#pragma once

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <vector>

#include "check.hpp"
#include "detector_bank.hpp"
#include "jordan_mlp.hpp"

namespace jordan_test {

namespace det = tactile::detector;
namespace simd = tactile::simd;

struct Rng {
    std::uint64_t s;
    double next() {  // uniform in [-1, 1)
        s = s * 6364136223846793005ULL + 1442695040888963407ULL;
        return double(s >> 11) / double(1ULL << 52) - 1.0;
    }
};

struct Weights {
    std::vector<double> w1, b1, w2, b2, mean, gain;
    Weights(int nin, int h, Rng& g) {
        for (int k = 0; k < h * (nin + 1); ++k) w1.push_back(1.5 * g.next());
        for (int k = 0; k < h; ++k) b1.push_back(g.next());
        for (int k = 0; k < 2 * h; ++k) w2.push_back(2.0 * g.next());
        for (int k = 0; k < 2; ++k) b2.push_back(g.next());
        for (int k = 0; k < nin; ++k) {
            mean.push_back(0.3 * g.next());
            gain.push_back(1.25 + 0.75 * g.next());
        }
    }
};

template <typename T>
int bits_differ(const std::vector<T>& a, const std::vector<T>& b) {
    int n = 0;
    for (std::size_t k = 0; k < a.size(); ++k) n += !(a[k] == b[k]);
    return n;
}

// Block run of n ticks (x: (R, nin, n) time last) against step() tick by tick and step_one().
template <typename T>
void check_mlp(int nin, int R, det::Activation act, simd::Isa isa, Rng& g) {
    const int H = 16, n = 150;
    Weights w(nin, H, g);
    det::JordanMLP<T> blk(nin, H, R, w.w1.data(), w.b1.data(), w.w2.data(), w.b2.data(), w.mean.data(),
                          w.gain.data(), act);
    det::JordanMLP<T> stp(nin, H, R, w.w1.data(), w.b1.data(), w.w2.data(), w.b2.data(), w.mean.data(),
                          w.gain.data(), act);
    det::JordanMLP<T> one(nin, H, R, w.w1.data(), w.b1.data(), w.w2.data(), w.b2.data(), w.mean.data(),
                          w.gain.data(), act);
    if (!blk.set_isa(isa) || !stp.set_isa(isa)) return;
    std::vector<T> x(std::size_t(R) * nin * n);
    for (auto& v : x) v = T(2.0 * g.next());
    std::vector<T> ys(std::size_t(R) * n), yn(ys.size()), yp(ys.size());
    blk.run(x.data(), std::ptrdiff_t(nin) * n, n, 1, n, ys.data(), yn.data(), yp.data(), n);
    std::vector<T> ss(ys.size()), sp(ys.size()), in(std::size_t(R) * nin), out(std::size_t(R) * 3), o1(3);
    double worst = 0.0;
    for (int t = 0; t < n; ++t) {
        for (int r = 0; r < R; ++r)
            for (int i = 0; i < nin; ++i) in[std::size_t(r) * nin + i] = x[(std::size_t(r) * nin + i) * n + t];
        stp.step(in.data(), out.data());
        for (int r = 0; r < R; ++r) {
            ss[std::size_t(r) * n + t] = out[3 * r];
            sp[std::size_t(r) * n + t] = out[3 * r + 2];
            one.step_one(r, in.data() + std::size_t(r) * nin, o1.data());
            worst = std::fmax(worst, std::fabs(double(o1[0]) - double(out[3 * r])));
            worst = std::fmax(worst, std::fabs(double(o1[2]) - double(out[3 * r + 2])));
        }
    }
    const char* tn = sizeof(T) == 4 ? "float" : "double";
    const char* an = act == det::Activation::exact ? "exact" : "fast";
    CHECK(bits_differ(ys, ss) == 0 && bits_differ(yp, sp) == 0, "%s %s %s, %d inputs, %d instances: block != step",
          tn, simd::isa_name(isa), an, nin, R);
    // the scalar reference sums in another order: round-off, amplified by the feedback
    const double tol = sizeof(T) == 4 ? 2e-4 : 1e-10;
    CHECK(worst <= tol, "%s %s %s, %d inputs, %d instances: step vs step_one %.3g", tn, simd::isa_name(isa), an, nin,
          R, worst);
    T st[64];
    blk.get_state(st);
    for (int r = 0; r < R; ++r) CHECK(st[r] == yp[std::size_t(r) * n + n - 1], "state after the block");
}

// step_feature_major's contract: the caller rewrites the vectors holding instances
// before every call; every other lane of its buffer (the ghosts past the last
// instance, in its last vector and in the vectors past it) may hold any finite value
// and changes nothing: the bits of step() on the same features, every tick.
template <typename T>
void check_feature_major(int nin, int R, simd::Isa isa, Rng& g) {
    const int H = 16, n = 40;
    Weights w(nin, H, g);
    det::JordanMLP<T> fm(nin, H, R, w.w1.data(), w.b1.data(), w.w2.data(), w.b2.data(), w.mean.data(),
                         w.gain.data(), det::Activation::exact);
    det::JordanMLP<T> stp(nin, H, R, w.w1.data(), w.b1.data(), w.w2.data(), w.b2.data(), w.mean.data(),
                          w.gain.data(), det::Activation::exact);
    if (!fm.set_isa(isa) || !stp.set_isa(isa)) return;
    const std::ptrdiff_t rs = fm.feature_major_stride();
    const int lanes = int(simd::Vec<T, 32>::lanes);  // the widest path's vector
    const std::ptrdiff_t held = ((R + lanes - 1) / lanes) * lanes;  // lanes any path rewrites
    std::vector<T> buf(std::size_t(nin) * std::size_t(rs)), in(std::size_t(R) * nin), o1(std::size_t(R) * 3),
        o2(o1.size());
    for (auto& v : buf) v = T(1e4 * g.next());  // finite garbage everywhere to start with
    int differ = 0;
    for (int t = 0; t < n; ++t) {
        for (int i = 0; i < nin; ++i)
            for (std::ptrdiff_t r = 0; r < held; ++r) {
                const T v = T(2.0 * g.next());
                if (r < R) in[std::size_t(r) * nin + i] = v;
                buf[std::size_t(i) * rs + r] = r < R ? v : T(1e3 * g.next());  // ghosts: anything finite
            }
        fm.step_feature_major(buf.data(), o1.data());
        stp.step(in.data(), o2.data());
        differ += bits_differ(o1, o2);
    }
    CHECK(differ == 0, "%s %s, %d inputs, %d instances: step_feature_major != step (%d values)",
          sizeof(T) == 4 ? "float" : "double", simd::isa_name(isa), nin, R, differ);
}

// The bank's block run (ridges in SIMD lanes, a scalar tail) against step(), bit for
// bit, with a bank of n_lp low-passes and n_abs |d| filters (4 and 2: the bundled
// net's, compiled with fixed counts; others: the run-time counts; 2 and 1 give 12
// features, the net's generic path), over n ticks (fewer than a vector of them: the
// scalar path alone), channel-major or, strided, time-major input (the scalar path);
// the filter states afterwards, the ghost lanes of the stored states (zero), and
// run()'s finiteness flag.
template <typename T>
void check_bank(int R, simd::Isa isa, Rng& g, int n_lp, int n_abs, int n, bool time_major, bool pad = false) {
    const double lp[4] = {0.005, 0.02, 0.08, 0.3}, ab[4] = {0.003, 0.01, 0.03, 0.1};
    const int nin = det::BankJordan<T>::input_count(n_lp, n_abs, pad), H = 16;
    Weights w(nin, H, g);
    if (!pad) {  // features in Pa/s and Pa (compressed, with the pad's mean: of order 1)
        for (auto& m : w.mean) m *= 1e3;
        for (auto& s : w.gain) s *= 1e-3;
    }
    std::vector<double> knee(static_cast<std::size_t>(nin));
    for (auto& k : knee) k = 300.0 * (1.5 + g.next());
    const double* kn = pad ? knee.data() : nullptr;
    det::BankJordan<T> blk(H, R, w.w1.data(), w.b1.data(), w.w2.data(), w.b2.data(), w.mean.data(), w.gain.data(),
                           1000.0, n_lp, lp, n_abs, ab, 0.5, 0.2, det::Activation::exact, kn, pad);
    det::BankJordan<T> stp(H, R, w.w1.data(), w.b1.data(), w.w2.data(), w.b2.data(), w.mean.data(), w.gain.data(),
                           1000.0, n_lp, lp, n_abs, ab, 0.5, 0.2, det::Activation::exact, kn, pad);
    if (!blk.net().set_isa(isa) || !stp.net().set_isa(isa)) return;
    // Channel i of ridge r at tick t: x[r * sr + i * si + t * st].
    const std::ptrdiff_t sr = time_major ? 4 : std::ptrdiff_t(4) * n, si = time_major ? 1 : n,
                         st = time_major ? std::ptrdiff_t(4) * R : 1;
    std::vector<T> x(std::size_t(R) * 4 * n);
    double acc = 0.0;
    for (std::size_t k = 0; k < x.size(); ++k) {
        acc += 300.0 * g.next();
        x[k] = T(acc + 500.0 * g.next());
    }
    std::vector<T> ys(std::size_t(R) * n), yn(ys.size()), yp(ys.size());
    CHECK(blk.run(x.data(), sr, si, st, n, ys.data(), yn.data(), yp.data(), n),
          "bank: finite inputs reported as non-finite");
    std::vector<T> ss(ys.size()), sp(ys.size()), in(std::size_t(R) * 4), out(std::size_t(R) * 3);
    for (int t = 0; t < n; ++t) {
        for (int r = 0; r < R; ++r)
            for (int i = 0; i < 4; ++i) in[std::size_t(r) * 4 + i] = x[r * sr + i * si + t * st];
        stp.step(in.data(), out.data());
        for (int r = 0; r < R; ++r) {
            ss[std::size_t(r) * n + t] = out[3 * r];
            sp[std::size_t(r) * n + t] = out[3 * r + 2];
        }
    }
    CHECK(bits_differ(ys, ss) == 0 && bits_differ(yp, sp) == 0,
          "bank %s %s, %d instances, %d/%d filters, %d ticks%s%s: block != step", sizeof(T) == 4 ? "float" : "double",
          simd::isa_name(isa), R, n_lp, n_abs, n, time_major ? " (time-major)" : "", pad ? ", pad mean + knees" : "");
    const int ns = blk.n_state();
    std::vector<T> pb(static_cast<std::size_t>(R)), ps(pb.size()), fb(static_cast<std::size_t>(R * ns)), fs(fb.size());
    blk.get_state(pb.data(), fb.data());
    stp.get_state(ps.data(), fs.data());
    CHECK(bits_differ(pb, ps) == 0 && bits_differ(fb, fs) == 0, "bank: states after block != after steps (%d ridges)",
          R);
    for (const auto* k : {&blk, &stp}) {
        const std::size_t stride = k->filter_state_size() / std::size_t(ns);
        int ghosts = 0;
        for (int j = 0; j < ns; ++j)
            for (std::size_t r = std::size_t(R); r < stride; ++r) ghosts += k->filter_state()[j * stride + r] != T(0);
        CHECK(stride >= std::size_t(R) && ghosts == 0, "bank: %d ghost lanes of the stored states are not zero",
              ghosts);
    }
    // A NaN or an Inf anywhere (a whole vector of ticks or the tail, any channel) is reported.
    for (std::size_t at : {std::size_t(0), x.size() / 2 + 3, x.size() - 1}) {
        for (T bad : {std::numeric_limits<T>::quiet_NaN(), -std::numeric_limits<T>::infinity()}) {
            std::vector<T> xb = x;
            xb[at] = bad;
            CHECK(!blk.run(xb.data(), sr, si, st, n, ys.data(), yn.data(), yp.data(), n),
                  "bank: a non-finite input at %zu not reported", at);
        }
    }
}

#define TM_JORDAN_CHECKS(EXTERN, T)                                                                       \
    EXTERN template void check_mlp<T>(int, int, det::Activation, simd::Isa, Rng&);                          \
    EXTERN template void check_feature_major<T>(int, int, simd::Isa, Rng&);                                  \
    EXTERN template void check_bank<T>(int, simd::Isa, Rng&, int, int, int, bool, bool);
TM_JORDAN_CHECKS(extern, float)
TM_JORDAN_CHECKS(extern, double)

}  // namespace jordan_test
