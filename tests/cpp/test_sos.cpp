// Stand-alone test of sos.hpp against a reference made by scipy (see
// tests/test_cpp_kernels.py), built with AddressSanitizer and UBSan.
//
// Input file (native endianness): u64 n_sections, channels, n; then
// sos[n_sections*6], x[channels*n], y_ref[channels*n] as float64.
// Checks process() (dispatched and baseline ISA, contiguous and strided, in
// chunks), step(), rejection of non-finite samples with state restore, float32.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include "sos.hpp"
#include "check.hpp"

using tactile::SosCascade;

template <typename T>
double max_err(const std::vector<T>& y, const std::vector<double>& ref) {
    double e = 0;
    for (size_t i = 0; i < y.size(); ++i) e = std::fmax(e, std::fabs(double(y[i]) - ref[i]));
    return e;
}

template <typename T>
void run(const std::vector<double>& sos, size_t ns, size_t ch, size_t n, const std::vector<double>& x64,
         const std::vector<double>& ref, double tol, bool baseline) {
    std::vector<T> x(x64.begin(), x64.end()), y(ch * n);
    SosCascade<T> k(sos.data(), ns, ch);
    if (baseline) k.set_isa(tactile::simd::Isa::baseline);
    size_t bt = 0, bc = 0;
    // in uneven chunks
    size_t t = 0, step = 1;
    while (t < n) {
        size_t m = std::min(step, n - t);
        CHECK(k.process(x.data() + t, std::ptrdiff_t(n), 1, y.data() + t, std::ptrdiff_t(n), 1, m, &bt, &bc),
              "process failed");
        t += m;
        step = step * 3 + 1;
    }
    CHECK(max_err(y, ref) <= tol, "chunked process error %g > %g", max_err(y, ref), tol);

    // time-major (strided) layout in one call
    std::vector<T> xt(ch * n), yt(ch * n);
    for (size_t c = 0; c < ch; ++c)
        for (size_t i = 0; i < n; ++i) xt[i * ch + c] = x[c * n + i];
    SosCascade<T> k2(sos.data(), ns, ch);
    if (baseline) k2.set_isa(tactile::simd::Isa::baseline);
    CHECK(k2.process(xt.data(), 1, std::ptrdiff_t(ch), yt.data(), 1, std::ptrdiff_t(ch), n, &bt, &bc), "strided");
    std::vector<T> back(ch * n);
    for (size_t c = 0; c < ch; ++c)
        for (size_t i = 0; i < n; ++i) back[c * n + i] = yt[i * ch + c];
    CHECK(max_err(back, ref) <= tol, "strided error %g", max_err(back, ref));

    // step() reproduces process() exactly
    SosCascade<T> k3(sos.data(), ns, ch);
    if (baseline) k3.set_isa(tactile::simd::Isa::baseline);
    std::vector<T> in(ch), out(ch);
    for (size_t i = 0; i < n; ++i) {
        for (size_t c = 0; c < ch; ++c) in[c] = x[c * n + i];
        k3.step(in.data(), out.data());
        for (size_t c = 0; c < ch; ++c) CHECK(out[c] == y[c * n + i], "step != process at %zu", i);
    }
    // a NaN sample: rejected, counted, state and output held
    std::vector<T> z0(ns * ch * 2), z1(ns * ch * 2);
    k3.get_state(z0.data());
    in[ch - 1] = T(NAN);
    CHECK(!k3.step(in.data(), out.data()), "NaN step accepted");
    CHECK(k3.rejected() == 1, "rejection not counted");
    k3.get_state(z1.data());
    CHECK(z0 == z1, "state changed by a rejected sample");
    // a block with an Inf: error position reported, state restored
    std::vector<T> xb(x.begin(), x.end());
    size_t bad_at = n / 2;
    xb[(ch / 2) * n + bad_at] = T(INFINITY);
    CHECK(!k3.process(xb.data(), std::ptrdiff_t(n), 1, y.data(), std::ptrdiff_t(n), 1, n, &bt, &bc), "Inf accepted");
    CHECK(bt == bad_at && bc == ch / 2, "bad sample at (%zu, %zu), expected (%zu, %zu)", bt, bc, bad_at, ch / 2);
    k3.get_state(z1.data());
    CHECK(z0 == z1, "state changed by a rejected block");
}

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s reference.bin\n", argv[0]);
        return 2;
    }
    FILE* f = std::fopen(argv[1], "rb");
    if (!f) return 2;
    unsigned long long hdr[3];
    if (std::fread(hdr, sizeof(hdr[0]), 3, f) != 3) return 2;
    size_t ns = hdr[0], ch = hdr[1], n = hdr[2];
    std::vector<double> sos(ns * 6), x(ch * n), ref(ch * n);
    if (std::fread(sos.data(), 8, sos.size(), f) != sos.size() || std::fread(x.data(), 8, x.size(), f) != x.size() ||
        std::fread(ref.data(), 8, ref.size(), f) != ref.size())
        return 2;
    std::fclose(f);
    double scale = 1;
    for (double v : ref) scale = std::fmax(scale, std::fabs(v));
    for (bool baseline : {false, true}) {
        run<double>(sos, ns, ch, n, x, ref, 1e-12 * scale, baseline);
        run<float>(sos, ns, ch, n, x, ref, 1e-4 * scale, baseline);
    }
    // bad construction throws (construction is the only place that may)
    bool threw = false;
    try {
        double bad[6] = {1, 0, 0, 0, 0, 0};
        SosCascade<double> k(bad, 1, 1);
    } catch (const std::invalid_argument&) {
        threw = true;
    }
    CHECK(threw, "a0 = 0 accepted");
    std::printf("%s: %d failures\n", failures ? "FAILED" : "ok", failures);
    return failures ? 1 : 0;
}
