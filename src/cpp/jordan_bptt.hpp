// Training-time kernel of the Jordan slip detector: the weighted cross-entropy
// loss and its exact backpropagation-through-time gradient, the same function as
// tactile_mirror.detector.network.loss_and_grad (the numpy specification) but
// one sequence at a time in C++, its padding skipped, sequences spread over
// threads.
//
// Why a second implementation: the numpy reference is vectorised over sequences
// and loops over time in Python, so its cost is ~10 interpreter-level array
// operations per time step whatever the batch. The C++ version does the ~250
// flops and 18 exponentials of a step directly; the training set can then be
// several times larger within the same training time.
//
// Determinism: sequences are cut into fixed blocks of kBlock, each block's loss
// and gradient are summed in sequence order, and the blocks are summed in block
// order, so the result does not depend on the number of threads.
//
// Off the real-time path: this allocates (per-thread workspaces, before any
// thread starts, so an allocation failure is an exception in the caller's
// thread) and may throw; the worker threads neither allocate nor throw.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <thread>
#include <vector>

#include "simd.hpp"

namespace tactile {
namespace detector {

struct BpttProblem {
    int n_inputs = 0;  // network inputs besides the feedback
    int n_hidden = 0;
    int n_seq = 0;
    std::ptrdiff_t n = 0;        // padded length (row stride of the (n_seq, n) arrays)
    const double* x = nullptr;   // (n_seq, n_inputs, n) normalised inputs
    const double* t_slip = nullptr;  // (n_seq, n) targets and per-sample loss weights
    const double* t_pred = nullptr;
    const double* w_slip = nullptr;
    const double* w_pred = nullptr;
    const std::ptrdiff_t* length = nullptr;  // (n_seq,) samples used of each row (<= n)
};

namespace bptt_detail {

// sigmoid(o) and the cross-entropy -t log(sigmoid(o)) - (1 - t) log(1 - sigmoid(o))
// = softplus(o) - t o, from one exponential, stable for any o.
inline double sigmoid_ce(double o, double t, double* ce) {
    const double e = std::exp(-std::fabs(o));
    const double r = 1.0 / (1.0 + e);
    *ce = std::max(o, 0.0) + std::log1p(e) - t * o;
    return o >= 0.0 ? r : e * r;
}

// Workspace of one thread, sized for the longest sequence.
struct Work {
    double* a;     // (max_len, H): input part of the pre-activations, then h, then dL/da
    double* ys;    // (max_len,)
    double* yp;    // (max_len,)
    double* acc;   // (n_inputs + 2, H): gradient of w1 (transposed) and b1 of one sequence
    double* w1t;   // (n_inputs + 1, H): w1 transposed, so the loops over hidden units are contiguous
};

// Loss of sequences [s0, s1) added to *loss, gradient to g (packed like theta).
// B: vector width (bytes) of the hidden-unit sigmoid (simd::kBaseBytes in the base
// variant, 32 in the AVX2 variant).
template <int B>
__attribute__((always_inline)) inline void run_block_impl(const BpttProblem& P, const double* theta, int s0, int s1,
                                                          double* loss, double* g, const Work& W) {
    const int H = P.n_hidden, m = P.n_inputs + 1, nin = P.n_inputs;
    const double* w1 = theta;               // (H, m)
    const double* b1 = w1 + H * m;          // (H,)
    const double* w2 = b1 + H;              // (2, H)
    const double* b2 = w2 + 2 * H;          // (2,)
    double* gw1 = g;
    double* gb1 = gw1 + H * m;
    double* gw2 = gb1 + H;
    double* gb2 = gw2 + 2 * H;
    for (int j = 0; j < H; ++j)
        for (int i = 0; i < m; ++i) W.w1t[i * H + j] = w1[j * m + i];
    const double* wfb = W.w1t + nin * H;
    for (int s = s0; s < s1; ++s) {
        const std::ptrdiff_t L = P.length[s];
        if (L <= 0) continue;
        const double* xs = P.x + std::ptrdiff_t(s) * nin * P.n;
        const double* ts = P.t_slip + std::ptrdiff_t(s) * P.n;
        const double* tp = P.t_pred + std::ptrdiff_t(s) * P.n;
        const double* ws = P.w_slip + std::ptrdiff_t(s) * P.n;
        const double* wp = P.w_pred + std::ptrdiff_t(s) * P.n;
        double* const A = W.a;
        double* const ys = W.ys;
        double* const yp = W.yp;
        // The input part of every pre-activation (no recurrence: off the dependency chain).
        for (std::ptrdiff_t t = 0; t < L; ++t) {
            double* a = A + t * H;
            for (int j = 0; j < H; ++j) a[j] = b1[j];
            for (int i = 0; i < nin; ++i) {
                const double xi = xs[i * P.n + t];
                const double* wr = W.w1t + i * H;
                for (int j = 0; j < H; ++j) a[j] += wr[j] * xi;
            }
        }
        // Forward: the recurrence; A[t] becomes the hidden activations h_t.
        double p = 0.0, l = 0.0;
        for (std::ptrdiff_t t = 0; t < L; ++t) {
            double* h = A + t * H;
            for (int j = 0; j < H; ++j) h[j] += wfb[j] * p;
            simd::sigmoid_array_impl<double, B, simd::Accuracy::exact>(h, h, std::size_t(H));
            double o0 = b2[0], o1 = b2[1];
            for (int j = 0; j < H; ++j) {
                o0 += w2[j] * h[j];
                o1 += w2[H + j] * h[j];
            }
            double ce0, ce1;
            const double y0 = sigmoid_ce(o0, ts[t], &ce0), y1 = sigmoid_ce(o1, tp[t], &ce1);
            ys[t] = y0;
            yp[t] = y1;
            p = y1;
            l += ws[t] * ce0 + wp[t] * ce1;
        }
        *loss += l;
        // Backward through time; g_p is dL/dp_t carried from step t + 1. A[t] becomes dL/da_t.
        double g_p = 0.0;
        for (std::ptrdiff_t t = L - 1; t >= 0; --t) {
            double* h = A + t * H;
            const double do_s = ws[t] * (ys[t] - ts[t]);
            const double do_p = wp[t] * (yp[t] - tp[t]) + g_p * yp[t] * (1.0 - yp[t]);
            gb2[0] += do_s;
            gb2[1] += do_p;
            double gp = 0.0;
            for (int j = 0; j < H; ++j) {
                gw2[j] += do_s * h[j];
                gw2[H + j] += do_p * h[j];
                const double d = (do_s * w2[j] + do_p * w2[H + j]) * h[j] * (1.0 - h[j]);
                h[j] = d;
                gp += d * wfb[j];
            }
            g_p = gp;
        }
        // dL/dw1 and dL/db1: sums over time of dL/da_t times the step's inputs.
        double* acc = W.acc;
        for (int k = 0; k < (nin + 2) * H; ++k) acc[k] = 0.0;
        for (std::ptrdiff_t t = 0; t < L; ++t) {
            const double* d = A + t * H;
            for (int i = 0; i < nin; ++i) {
                const double xi = xs[i * P.n + t];
                double* ar = acc + i * H;
                for (int j = 0; j < H; ++j) ar[j] += d[j] * xi;
            }
            const double pp = t > 0 ? yp[t - 1] : 0.0;
            double* af = acc + nin * H;
            double* ab = acc + (nin + 1) * H;
            for (int j = 0; j < H; ++j) {
                af[j] += d[j] * pp;
                ab[j] += d[j];
            }
        }
        for (int j = 0; j < H; ++j) {
            for (int i = 0; i < m; ++i) gw1[j * m + i] += acc[i * H + j];
            gb1[j] += acc[(nin + 1) * H + j];
        }
    }
}

// The same code compiled per variant of the SIMD layer; the loops over hidden
// units vectorise (O3) in the AVX2+FMA copy.
__attribute__((optimize("O3"))) inline void run_block_base(const BpttProblem& P, const double* theta, int s0,
                                                            int s1, double* loss, double* g, const Work& W) {
    run_block_impl<simd::kBaseBytes>(P, theta, s0, s1, loss, g, W);
}
#if TM_HAVE_DISPATCH
TM_TARGET_AVX2 __attribute__((optimize("O3"), noinline)) inline void run_block_avx2(
    const BpttProblem& P, const double* theta, int s0, int s1, double* loss, double* g, const Work& W) {
    run_block_impl<32>(P, theta, s0, s1, loss, g, W);
}
#endif

inline void run_block(const BpttProblem& P, const double* theta, int s0, int s1, double* loss, double* g,
                      const Work& W, simd::Isa isa) {
#if TM_HAVE_DISPATCH
    if (isa == simd::Isa::avx2_fma) return run_block_avx2(P, theta, s0, s1, loss, g, W);
#endif
    (void)isa;
    run_block_base(P, theta, s0, s1, loss, g, W);
}

}  // namespace bptt_detail

// Sequences per deterministic block.
constexpr int kBpttBlock = 8;

// Loss and gradient (packed w1, b1, w2, b2; size H*(n_inputs+1) + H + 2H + 2)
// over all sequences, with n_threads worker threads (>= 1). No regularisation.
inline double jordan_loss_grad(const BpttProblem& P, const double* theta, double* grad, int n_threads) {
    if (P.n_inputs < 1 || P.n_hidden < 1 || P.n_seq < 0 || P.n < 0)
        throw std::invalid_argument("jordan_loss_grad: bad sizes");
    const int H = P.n_hidden, m = P.n_inputs + 1;
    const std::size_t n_par = std::size_t(H) * m + H + 2 * H + 2;
    const int n_blocks = (P.n_seq + kBpttBlock - 1) / kBpttBlock;
    std::vector<double> block_loss(std::size_t(std::max(n_blocks, 1)), 0.0);
    std::vector<double> block_grad(std::size_t(std::max(n_blocks, 1)) * n_par, 0.0);
    const int nt = std::max(1, std::min(n_threads, std::max(n_blocks, 1)));
    std::ptrdiff_t max_len = 0;
    for (int s = 0; s < P.n_seq; ++s) {
        if (P.length[s] < 0 || P.length[s] > P.n) throw std::invalid_argument("jordan_loss_grad: bad length");
        max_len = std::max(max_len, P.length[s]);
    }
    // Per thread: see bptt_detail::Work.
    const std::size_t per = std::size_t(max_len) * (H + 2) + std::size_t(2 * m + 1) * H;
    std::vector<double> work_mem(per * nt);
    const simd::Isa isa = simd::detect_isa();
    auto work = [&](int k) {
        bptt_detail::Work W;
        W.a = work_mem.data() + per * k;
        W.ys = W.a + max_len * H;
        W.yp = W.ys + max_len;
        W.acc = W.yp + max_len;
        W.w1t = W.acc + (m + 1) * H;
        for (int b = k; b < n_blocks; b += nt) {
            const int s0 = b * kBpttBlock, s1 = std::min(P.n_seq, s0 + kBpttBlock);
            bptt_detail::run_block(P, theta, s0, s1, &block_loss[b], &block_grad[std::size_t(b) * n_par], W, isa);
        }
    };
    if (nt == 1) {
        work(0);
    } else {
        std::vector<std::thread> pool;
        pool.reserve(std::size_t(nt - 1));
        for (int k = 1; k < nt; ++k) {
            try {
                pool.emplace_back(work, k);
            } catch (...) {  // no thread to be had: this thread does the stripe
                break;
            }
        }
        for (int k = 1 + int(pool.size()); k < nt; ++k) work(k);
        work(0);
        for (auto& th : pool) th.join();
    }
    double loss = 0.0;
    std::fill(grad, grad + n_par, 0.0);
    for (int b = 0; b < n_blocks; ++b) {
        loss += block_loss[b];
        const double* gb = &block_grad[std::size_t(b) * n_par];
        for (std::size_t k = 0; k < n_par; ++k) grad[k] += gb[k];
    }
    return loss;
}

}  // namespace detector
}  // namespace tactile
