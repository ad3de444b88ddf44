// Stand-alone test of jordan_bptt.hpp (training loss and exact BPTT gradient)
// against a reference made by the numpy specification (see
// tests/test_cpp_kernels.py), built with AddressSanitizer and UBSan.
//
// Input file (native endianness): u64 n_inputs, n_hidden, n_seq, n; then as
// float64: theta[n_par], x[n_seq*n_inputs*n], t_slip, t_pred, w_slip, w_pred
// [n_seq*n each]; i64 length[n_seq]; float64 loss_ref, grad_ref[n_par].
// Checks 1-4 threads (bit-identical to each other), and that bad lengths throw.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <stdexcept>
#include <vector>

#include "jordan_bptt.hpp"
#include "check.hpp"

int main(int argc, char** argv) {
    if (argc != 2) return 2;
    std::FILE* f = std::fopen(argv[1], "rb");
    if (!f) return 2;
    auto head = read<std::uint64_t>(f, 4);
    const int nin = int(head[0]), H = int(head[1]), S = int(head[2]);
    const std::ptrdiff_t n = std::ptrdiff_t(head[3]);
    const std::size_t n_par = std::size_t(H) * (nin + 1) + 3 * std::size_t(H) + 2;
    auto theta = read<double>(f, n_par);
    auto x = read<double>(f, std::size_t(S) * nin * n);
    auto ts = read<double>(f, std::size_t(S) * n);
    auto tp = read<double>(f, std::size_t(S) * n);
    auto ws = read<double>(f, std::size_t(S) * n);
    auto wp = read<double>(f, std::size_t(S) * n);
    auto len64 = read<std::int64_t>(f, std::size_t(S));
    auto loss_ref = read<double>(f, 1);
    auto grad_ref = read<double>(f, n_par);
    std::fclose(f);
    std::vector<std::ptrdiff_t> length(len64.begin(), len64.end());

    tactile::detector::BpttProblem P;
    P.n_inputs = nin;
    P.n_hidden = H;
    P.n_seq = S;
    P.n = n;
    P.x = x.data();
    P.t_slip = ts.data();
    P.t_pred = tp.data();
    P.w_slip = ws.data();
    P.w_pred = wp.data();
    P.length = length.data();

    double gmax = 0;
    for (double g : grad_ref) gmax = std::fmax(gmax, std::fabs(g));
    std::vector<double> g1(n_par);
    const double l1 = tactile::detector::jordan_loss_grad(P, theta.data(), g1.data(), 1);
    CHECK(std::fabs(l1 - loss_ref[0]) <= 1e-12 * std::fabs(loss_ref[0]), "loss %.17g vs %.17g", l1, loss_ref[0]);
    for (std::size_t k = 0; k < n_par; ++k)
        CHECK(std::fabs(g1[k] - grad_ref[k]) <= 1e-12 * gmax, "grad[%zu] %.17g vs %.17g", k, g1[k], grad_ref[k]);
    for (int nt = 2; nt <= 4; ++nt) {
        std::vector<double> g(n_par);
        const double l = tactile::detector::jordan_loss_grad(P, theta.data(), g.data(), nt);
        CHECK(l == l1, "loss with %d threads differs", nt);
        for (std::size_t k = 0; k < n_par; ++k) CHECK(g[k] == g1[k], "grad[%zu] with %d threads differs", k, nt);
    }
    // A length beyond the row throws (in the caller's thread) and writes nothing.
    std::vector<std::ptrdiff_t> bad(length);
    bad[0] = n + 1;
    P.length = bad.data();
    std::vector<double> g(n_par, 7.0);
    bool threw = false;
    try {
        tactile::detector::jordan_loss_grad(P, theta.data(), g.data(), 2);
    } catch (const std::invalid_argument&) {
        threw = true;
    }
    CHECK(threw, "bad length did not throw");
    CHECK(g[0] == 7.0, "grad written despite the error");
    std::printf("ok: %d failures\n", failures);
    return failures ? 1 : 0;
}
