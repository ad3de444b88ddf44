// The small dense linear algebra of the contact solver (contact_solver.hpp): the LU
// factorisation with partial pivoting, its triangular solves, dot products, the
// bordered solve's column update and the compliance product u = C P lam.
//
// Each kernel is a struct K whose static member template K::run<B> is the kernel over
// B-byte vectors, written once; simd::Dispatch<K> compiles it for the x86-64 baseline
// and for AVX2+FMA, and the entry points below (lu_factor, lu_solve, ...) pick the
// variant at run time (contact_detail::use_avx2; simd::set_baseline forces the
// baseline). All of them allocate nothing and throw nothing.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstring>

#include "simd.hpp"

namespace tactile {

// Dense LU with partial pivoting of a row-major m x m matrix `a` (leading dimension
// lda), in place; piv[k] is the row swapped with row k. Returns 0, or k + 1 when the
// pivot of column k is exactly zero (the factorisation stops there).
//
// Blocked right-looking (as LAPACK getrf): a panel of kLuBlock columns is factored
// with partial pivoting (rows swapped whole), the block row of U is solved with the
// panel's unit lower triangle, and the trailing matrix gets one rank-kLuBlock update.
// The update loads and stores each trailing entry once per panel instead of once per
// column, with the panel's U rows held in L1: what makes it fast for m of a few
// hundred.
constexpr std::size_t kLuBlock = 8;

// The dense kernels below (the LU, its triangular solves, the dot products and the
// compliance product u = C P lam) are where a step spends its time. Each is written
// once over B-byte vectors and compiled twice (simd.hpp): the x86-64 baseline and an
// AVX2+FMA variant chosen at run time; on AVX2 hardware a 4-wide fused
// multiply-add replaces two 2-wide SSE2 multiplies and adds (measured on fig6: the
// step's median about halves). The two variants round differently (FMA, summation
// order); both stay within round-off of the Python reference (tests/test_contact_cpp.py).

// ri[j] -= sum_t ri[kb + t] * U[t][j] for j in [ke, m), t < 8: one row of the
// trailing update with a full panel. Written out so that the eight multipliers and
// the partial sums stay in registers; the two partial sums halve the dependency chain.
template <int B>
TM_ALWAYS_INLINE void lu_update_row8(double* ri, const double* U, std::size_t lda, std::size_t kb, std::size_t ke,
                                     std::size_t m) noexcept {
    const double l0 = ri[kb], l1 = ri[kb + 1], l2 = ri[kb + 2], l3 = ri[kb + 3];
    const double l4 = ri[kb + 4], l5 = ri[kb + 5], l6 = ri[kb + 6], l7 = ri[kb + 7];
    const double *u0 = U, *u1 = U + lda, *u2 = U + 2 * lda, *u3 = U + 3 * lda;
    const double *u4 = U + 4 * lda, *u5 = U + 5 * lda, *u6 = U + 6 * lda, *u7 = U + 7 * lda;
    std::size_t j = ke;
    if (m - ke >= 4) {  // 4-wide (two SSE2 registers on the baseline, one AVX register); no loop-carried value
        using V = typename simd::Vec<double, 32>::type;
        const V v0 = simd::splat<double, 32>(l0), v1 = simd::splat<double, 32>(l1);
        const V v2 = simd::splat<double, 32>(l2), v3 = simd::splat<double, 32>(l3);
        const V v4 = simd::splat<double, 32>(l4), v5 = simd::splat<double, 32>(l5);
        const V v6 = simd::splat<double, 32>(l6), v7 = simd::splat<double, 32>(l7);
        for (; j + 4 <= m; j += 4) {
            const V s0 = v0 * simd::load<V>(u0 + j) + v1 * simd::load<V>(u1 + j) +
                         v2 * simd::load<V>(u2 + j) + v3 * simd::load<V>(u3 + j);
            const V s1 = v4 * simd::load<V>(u4 + j) + v5 * simd::load<V>(u5 + j) +
                         v6 * simd::load<V>(u6 + j) + v7 * simd::load<V>(u7 + j);
            const V r = simd::load<V>(ri + j) - (s0 + s1);
            std::memcpy(ri + j, &r, sizeof(r));
        }
    }
    for (; j < m; ++j) {
        const double s0 = l0 * u0[j] + l1 * u1[j] + l2 * u2[j] + l3 * u3[j];
        const double s1 = l4 * u4[j] + l5 * u5[j] + l6 * u6[j] + l7 * u7[j];
        ri[j] -= s0 + s1;
    }
}

// A double into the four lanes: one broadcast load in the AVX variant (B = 32), a
// splat on the baseline.
template <int B>
TM_ALWAYS_INLINE typename simd::Vec<double, 32>::type lu_bcast(const double* p) noexcept {
    if constexpr (B == 32) return simd::bcast<double, 32>(p);
    else return simd::splat<double, 32>(*p);
}

// Rows r0..r3 of the trailing update with a full panel, rj[j] -= sum_t rj[kb + t] U[t][j]
// for j in [ke, m): a 4 x 8 block of the rows in eight accumulators, each row's eight
// multipliers broadcast from memory and each U row's two vectors loaded once for the
// four rows (six loads per eight multiply-adds, where one row at a time loads nine
// per eight and holds eight splats that do not fit the registers with the rest):
// about 1.4x faster factorisations for m of 200-320. AVX variant only: with 16-byte
// vectors the block's sixteen registers spill (the baseline keeps lu_update_row8).
template <int B>
TM_ALWAYS_INLINE void lu_update_rows4(double* r0, double* r1, double* r2, double* r3, const double* U,
                                      std::size_t lda, std::size_t kb, std::size_t ke, std::size_t m) noexcept {
    using V = typename simd::Vec<double, 32>::type;
    std::size_t j = ke;
    for (; j + 8 <= m; j += 8) {
        V a0 = simd::load<V>(r0 + j), b0 = simd::load<V>(r0 + j + 4);
        V a1 = simd::load<V>(r1 + j), b1 = simd::load<V>(r1 + j + 4);
        V a2 = simd::load<V>(r2 + j), b2 = simd::load<V>(r2 + j + 4);
        V a3 = simd::load<V>(r3 + j), b3 = simd::load<V>(r3 + j + 4);
        for (std::size_t t = 0; t < kLuBlock; ++t) {
            const double* ut = U + t * lda + j;
            const V u0 = simd::load<V>(ut), u1 = simd::load<V>(ut + 4);
            V l = lu_bcast<B>(r0 + kb + t);
            a0 -= l * u0; b0 -= l * u1;
            l = lu_bcast<B>(r1 + kb + t);
            a1 -= l * u0; b1 -= l * u1;
            l = lu_bcast<B>(r2 + kb + t);
            a2 -= l * u0; b2 -= l * u1;
            l = lu_bcast<B>(r3 + kb + t);
            a3 -= l * u0; b3 -= l * u1;
        }
        std::memcpy(r0 + j, &a0, sizeof(a0)); std::memcpy(r0 + j + 4, &b0, sizeof(b0));
        std::memcpy(r1 + j, &a1, sizeof(a1)); std::memcpy(r1 + j + 4, &b1, sizeof(b1));
        std::memcpy(r2 + j, &a2, sizeof(a2)); std::memcpy(r2 + j + 4, &b2, sizeof(b2));
        std::memcpy(r3 + j, &a3, sizeof(a3)); std::memcpy(r3 + j + 4, &b3, sizeof(b3));
    }
    if (j + 4 <= m) {
        V a0 = simd::load<V>(r0 + j), a1 = simd::load<V>(r1 + j);
        V a2 = simd::load<V>(r2 + j), a3 = simd::load<V>(r3 + j);
        for (std::size_t t = 0; t < kLuBlock; ++t) {
            const V u0 = simd::load<V>(U + t * lda + j);
            a0 -= lu_bcast<B>(r0 + kb + t) * u0; a1 -= lu_bcast<B>(r1 + kb + t) * u0;
            a2 -= lu_bcast<B>(r2 + kb + t) * u0; a3 -= lu_bcast<B>(r3 + kb + t) * u0;
        }
        std::memcpy(r0 + j, &a0, sizeof(a0)); std::memcpy(r1 + j, &a1, sizeof(a1));
        std::memcpy(r2 + j, &a2, sizeof(a2)); std::memcpy(r3 + j, &a3, sizeof(a3));
        j += 4;
    }
    for (; j < m; ++j) {
        double a0 = r0[j], a1 = r1[j], a2 = r2[j], a3 = r3[j];
        for (std::size_t t = 0; t < kLuBlock; ++t) {
            const double u = U[t * lda + j];
            a0 -= r0[kb + t] * u; a1 -= r1[kb + t] * u; a2 -= r2[kb + t] * u; a3 -= r3[kb + t] * u;
        }
        r0[j] = a0; r1[j] = a1; r2[j] = a2; r3[j] = a3;
    }
}

// lu_factor (see the top of this file).
struct LuFactor {
    template <int B>
    static TM_ALWAYS_INLINE int run(double* a, std::size_t m, std::size_t lda, int* piv) noexcept {
        for (std::size_t kb = 0; kb < m; kb += kLuBlock) {
            const std::size_t b = m - kb < kLuBlock ? m - kb : kLuBlock;
            const std::size_t ke = kb + b;
            // panel: columns kb..ke-1, all rows below
            for (std::size_t k = kb; k < ke; ++k) {
                std::size_t p = k;
                double best = std::fabs(a[k * lda + k]);
                for (std::size_t i = k + 1; i < m; ++i) {
                    const double v = std::fabs(a[i * lda + k]);
                    if (v > best) { best = v; p = i; }  // first maximum, as idamax
                }
                piv[k] = static_cast<int>(p);
                if (a[p * lda + k] == 0.0) return static_cast<int>(k) + 1;
                if (p != k) {
                    double* rk = a + k * lda;
                    double* rp = a + p * lda;
                    for (std::size_t j = 0; j < m; ++j) { const double t = rk[j]; rk[j] = rp[j]; rp[j] = t; }
                }
                const double* rk = a + k * lda;
                const double inv = 1.0 / rk[k];
                for (std::size_t i = k + 1; i < m; ++i) {
                    double* ri = a + i * lda;
                    const double l = ri[k] * inv;
                    ri[k] = l;
                    for (std::size_t j = k + 1; j < ke; ++j) ri[j] -= l * rk[j];
                }
            }
            if (ke >= m) break;
            // block row of U: L11 U12 = A12 (unit lower triangular)
            for (std::size_t k = kb; k < ke; ++k) {
                const double* rk = a + k * lda;
                for (std::size_t i = k + 1; i < ke; ++i) {
                    double* ri = a + i * lda;
                    const double l = ri[k];
                    for (std::size_t j = ke; j < m; ++j) ri[j] -= l * rk[j];
                }
            }
            // trailing update A22 -= L21 U12
            if (b == kLuBlock) {
                std::size_t i = ke;
                if constexpr (B == 32) {  // the 4 x 8 blocks need the sixteen AVX registers
                    for (; i + 4 <= m; i += 4) {
                        double* r0 = a + i * lda;
                        lu_update_rows4<B>(r0, r0 + lda, r0 + 2 * lda, r0 + 3 * lda, a + kb * lda, lda, kb, ke, m);
                    }
                }
                for (; i < m; ++i) lu_update_row8<B>(a + i * lda, a + kb * lda, lda, kb, ke, m);
            } else {
                for (std::size_t i = ke; i < m; ++i) {
                    double* ri = a + i * lda;
                    for (std::size_t j = ke; j < m; ++j) {
                        double acc = ri[j];
                        for (std::size_t t = 0; t < b; ++t) acc -= ri[kb + t] * a[(kb + t) * lda + j];
                        ri[j] = acc;
                    }
                }
            }
        }
        return 0;
    }
};

// sum_j a[j] b[j]: two 4-wide partial sums (eight independent lanes) so that the
// loop is bound by the loads, not by the add latency of one running sum.
struct Dot {
    template <int B>
    static TM_ALWAYS_INLINE double run(const double* a, const double* b, std::size_t m) noexcept {
        using V = typename simd::Vec<double, 32>::type;
        std::size_t j = 0;
        double s = 0.0;
        if (m >= 8) {
            V s0 = simd::splat<double, 32>(0.0), s1 = s0;
            for (; j + 8 <= m; j += 8) {
                s0 += simd::load<V>(a + j) * simd::load<V>(b + j);
                s1 += simd::load<V>(a + j + 4) * simd::load<V>(b + j + 4);
            }
            s0 += s1;
            s = (s0[0] + s0[1]) + (s0[2] + s0[3]);
        }
        for (; j < m; ++j) s += a[j] * b[j];
        return s;
    }
};

// s[q] = sum_j r_q[j] x[j] over j < len for four rows r_0..r_3: one load of x feeds
// the four rows and their four sums are reduced together, so a triangular solve pays
// one horizontal reduction per four rows; two partial sums per row (eight independent
// chains) keep the loop bound by the loads, not by the FMA latency.
struct RowsDot4 {
    template <int B>
    static TM_ALWAYS_INLINE void run(const double* r0, const double* r1, const double* r2, const double* r3,
                                     const double* x, std::size_t len, double* s) noexcept {
        using V = typename simd::Vec<double, 32>::type;
        std::size_t j = 0;
        double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
        if (len >= 4) {
            V a0 = simd::splat<double, 32>(0.0), a1 = a0, a2 = a0, a3 = a0;
            V b0 = a0, b1 = a0, b2 = a0, b3 = a0;
            for (; j + 8 <= len; j += 8) {
                const V x0 = simd::load<V>(x + j), x1 = simd::load<V>(x + j + 4);
                a0 += simd::load<V>(r0 + j) * x0; b0 += simd::load<V>(r0 + j + 4) * x1;
                a1 += simd::load<V>(r1 + j) * x0; b1 += simd::load<V>(r1 + j + 4) * x1;
                a2 += simd::load<V>(r2 + j) * x0; b2 += simd::load<V>(r2 + j + 4) * x1;
                a3 += simd::load<V>(r3 + j) * x0; b3 += simd::load<V>(r3 + j + 4) * x1;
            }
            if (j + 4 <= len) {
                const V x0 = simd::load<V>(x + j);
                a0 += simd::load<V>(r0 + j) * x0; a1 += simd::load<V>(r1 + j) * x0;
                a2 += simd::load<V>(r2 + j) * x0; a3 += simd::load<V>(r3 + j) * x0;
                j += 4;
            }
            a0 += b0; a1 += b1; a2 += b2; a3 += b3;
            s0 = (a0[0] + a0[1]) + (a0[2] + a0[3]);
            s1 = (a1[0] + a1[1]) + (a1[2] + a1[3]);
            s2 = (a2[0] + a2[1]) + (a2[2] + a2[3]);
            s3 = (a3[0] + a3[1]) + (a3[2] + a3[3]);
        }
        for (; j < len; ++j) {
            s0 += r0[j] * x[j]; s1 += r1[j] * x[j]; s2 += r2[j] * x[j]; s3 += r3[j] * x[j];
        }
        s[0] = s0; s[1] = s1; s[2] = s2; s[3] = s3;
    }
};

// Solve with the factors of lu_factor for k right-hand sides, column c at x + c * ldx
// (length m), overwritten by the solutions. Four rows at a time (RowsDot4 against the
// solved part, then the 4 x 4 triangle): the solve reads each factor entry once, as the
// one-row version, with a quarter of its reductions and loop overheads (about twice as
// fast for m of a few hundred). The columns are taken inside the row loop, so the four
// rows stream from L2 / L3 once and are reread from L1 for the other columns; each
// column's arithmetic is that of a solve on its own.
struct LuForward {
    template <int B>
    static TM_ALWAYS_INLINE void run(const double* lu, std::size_t m, std::size_t lda, const int* piv, double* x,
                                     std::size_t ldx, std::size_t k) noexcept {
        for (std::size_t c = 0; c < k; ++c) {
            double* b = x + c * ldx;
            for (std::size_t r = 0; r < m; ++r) {
                const std::size_t p = static_cast<std::size_t>(piv[r]);
                if (p != r) { const double t = b[r]; b[r] = b[p]; b[p] = t; }
            }
        }
        double s[4];
        std::size_t i = 0;
        for (; i + 4 <= m; i += 4) {  // L y = P b, unit diagonal
            const double *r0 = lu + i * lda, *r1 = r0 + lda, *r2 = r1 + lda, *r3 = r2 + lda;
            for (std::size_t c = 0; c < k; ++c) {
                double* b = x + c * ldx;
                RowsDot4::run<B>(r0, r1, r2, r3, b, i, s);
                const double y0 = b[i] - s[0];
                const double y1 = b[i + 1] - (s[1] + r1[i] * y0);
                const double y2 = b[i + 2] - (s[2] + r2[i] * y0 + r2[i + 1] * y1);
                const double y3 = b[i + 3] - (s[3] + r3[i] * y0 + r3[i + 1] * y1 + r3[i + 2] * y2);
                b[i] = y0; b[i + 1] = y1; b[i + 2] = y2; b[i + 3] = y3;
            }
        }
        for (; i < m; ++i)
            for (std::size_t c = 0; c < k; ++c) x[c * ldx + i] -= Dot::run<B>(lu + i * lda, x + c * ldx, i);
    }
};

template <int B>
TM_ALWAYS_INLINE void lu_backward(const double* lu, std::size_t m, std::size_t lda, double* x, std::size_t ldx,
                                  std::size_t k) noexcept {
    double s[4];
    std::size_t e = m;  // U x = y; rows [e, m) solved
    while (e % 4) {
        --e;
        const double* re = lu + e * lda;
        for (std::size_t c = 0; c < k; ++c) {
            double* b = x + c * ldx;
            b[e] = (b[e] - Dot::run<B>(re + e + 1, b + e + 1, m - e - 1)) / re[e];
        }
    }
    while (e >= 4) {
        const std::size_t i0 = e - 4;
        const double *r0 = lu + i0 * lda, *r1 = r0 + lda, *r2 = r1 + lda, *r3 = r2 + lda;
        for (std::size_t c = 0; c < k; ++c) {
            double* b = x + c * ldx;
            RowsDot4::run<B>(r0 + e, r1 + e, r2 + e, r3 + e, b + e, m - e, s);
            const double x3 = (b[i0 + 3] - s[3]) / r3[i0 + 3];
            const double x2 = (b[i0 + 2] - (s[2] + r2[i0 + 3] * x3)) / r2[i0 + 2];
            const double x1 = (b[i0 + 1] - (s[1] + r1[i0 + 2] * x2 + r1[i0 + 3] * x3)) / r1[i0 + 1];
            const double x0 = (b[i0] - (s[0] + r0[i0 + 1] * x1 + r0[i0 + 2] * x2 + r0[i0 + 3] * x3)) / r0[i0];
            b[i0] = x0; b[i0 + 1] = x1; b[i0 + 2] = x2; b[i0 + 3] = x3;
        }
        e = i0;
    }
}

// lu_solve: LuForward, then U x = y (lu_backward); one right-hand side x by default.
struct LuSolve {
    template <int B>
    static TM_ALWAYS_INLINE void run(const double* lu, std::size_t m, std::size_t lda, const int* piv, double* x,
                                     std::size_t ldx = 0, std::size_t k = 1) noexcept {
        LuForward::run<B>(lu, m, lda, piv, x, ldx, k);
        lu_backward<B>(lu, m, lda, x, ldx, k);
    }
};

// Row vectors x_r (k of them, row r at x + r * ldx) overwritten by x_r U^-1 for the upper
// factor U of lu_factor (the rows of a block appended below the factored matrix,
// extend_base): column by column, x_r[j] /= U[j][j] and the rest of the row loses
// x_r[j] U[j][j+1:], an axpy along a row of U that stays in L1 for the k rows.
struct LuRightUpper {
    template <int B>
    static TM_ALWAYS_INLINE void run(const double* lu, std::size_t m, std::size_t lda, double* x,
                                     std::size_t ldx, std::size_t k) noexcept {
        using V = typename simd::Vec<double, 32>::type;
        for (std::size_t j = 0; j < m; ++j) {
            const double* uj = lu + j * lda;
            const double d = uj[j];
            for (std::size_t r = 0; r < k; ++r) {
                double* xr = x + r * ldx;
                const double a = xr[j] / d;
                xr[j] = a;
                if (a == 0.0) continue;
                const V av = simd::splat<double, 32>(a);
                std::size_t i = j + 1;
                for (; i + 4 <= m; i += 4) {
                    const V v = simd::load<V>(xr + i) - av * simd::load<V>(uj + i);
                    std::memcpy(xr + i, &v, sizeof(v));
                }
                for (; i < m; ++i) xr[i] -= a * uj[i];
            }
        }
    }
};

// z[k] -= sum_c V_c[k] y[c] for k < m, nb columns V_c at V[c]: the border's
// correction of a bordered solve (solve_bordered), four entries of z at a time through
// all the columns (each column's term in column order, as one axpy per column would
// add them), so z is loaded and stored once instead of once per column.
struct SubColumns {
    template <int B>
    static TM_ALWAYS_INLINE void run(double* z, std::size_t m, const double* const* V, const double* y,
                                     std::size_t nb) noexcept {
        using V4 = typename simd::Vec<double, 32>::type;
        std::size_t k = 0;
        for (; k + 4 <= m; k += 4) {
            V4 a = simd::load<V4>(z + k);
            for (std::size_t c = 0; c < nb; ++c) a -= simd::load<V4>(V[c] + k) * lu_bcast<B>(y + c);
            std::memcpy(z + k, &a, sizeof(a));
        }
        for (; k < m; ++k) {
            double a = z[k];
            for (std::size_t c = 0; c < nb; ++c) a -= V[c][k] * y[c];
            z[k] = a;
        }
    }
};

// u = C P lam for the symmetric (m x m, m = 2n) compliance C, P = diag(1, -1):
// column j of C P is row j of C (sign-flipped for the normal block); only the
// nonzero forces contribute (open nodes carry none).
struct ComplianceProduct {
    template <int B>
    static TM_ALWAYS_INLINE void run(const double* C, std::size_t n, const double* lam, double* u) noexcept {
        const std::size_t n2 = 2 * n;
        using V = typename simd::Vec<double, 32>::type;
        for (std::size_t i = 0; i < n2; ++i) u[i] = 0.0;
        // two columns per pass: half the loads and stores of u
        std::size_t j = 0, jn = 0;
        auto next = [&](std::size_t from) {
            while (from < n2 && lam[from] == 0.0) ++from;
            return from;
        };
        j = next(0);
        while (j < n2) {
            jn = next(j + 1);
            const double a = j < n ? lam[j] : -lam[j];
            const double* cj = C + j * n2;
            const V av = simd::splat<double, 32>(a);
            std::size_t i = 0;
            if (jn < n2) {
                const double a2 = jn < n ? lam[jn] : -lam[jn];
                const double* ck = C + jn * n2;
                const V bv = simd::splat<double, 32>(a2);
                for (; i + 4 <= n2; i += 4) {
                    const V r = simd::load<V>(u + i) + simd::load<V>(cj + i) * av + simd::load<V>(ck + i) * bv;
                    std::memcpy(u + i, &r, sizeof(r));
                }
                for (; i < n2; ++i) u[i] += cj[i] * a + ck[i] * a2;
                j = next(jn + 1);
            } else {
                for (; i + 4 <= n2; i += 4) {
                    const V r = simd::load<V>(u + i) + simd::load<V>(cj + i) * av;
                    std::memcpy(u + i, &r, sizeof(r));
                }
                for (; i < n2; ++i) u[i] += cj[i] * a;
                j = jn;
            }
        }
    }
};

namespace contact_detail {
// The AVX2+FMA variants run when the SIMD layer's choice is AVX2+FMA: the CPU has
// them and the process-wide baseline switch (simd::set_baseline) is off. Consulted
// at every call, so the switch acts on solvers already built.
inline bool use_avx2() noexcept {
#if TM_HAVE_DISPATCH
    return simd::detect_isa() == simd::Isa::avx2_fma;
#else
    return false;
#endif
}

// The entry point of a dense kernel K: its AVX2+FMA variant when use_avx2(), else
// its baseline variant (simd::Dispatch).
template <class K>
struct Dispatched {
    template <class... A>
    auto operator()(A... a) const noexcept {
        return simd::Dispatch<K>::run(use_avx2(), a...);
    }
};
}  // namespace contact_detail

// The variant the contact kernels run now, by the SIMD layer's names (simd::isa_name):
// "avx2+fma", or the base variant ("sse2" on x86-64, "native" in a TM_NATIVE build).
inline const char* contact_simd_path() noexcept { return simd::isa_name(simd::detect_isa()); }

// The kernels' entry points, called as functions (arguments as K::run's).
inline constexpr contact_detail::Dispatched<LuFactor> lu_factor{};
inline constexpr contact_detail::Dispatched<LuForward> lu_forward{};
inline constexpr contact_detail::Dispatched<LuSolve> lu_solve{};
inline constexpr contact_detail::Dispatched<LuRightUpper> lu_right_upper{};
inline constexpr contact_detail::Dispatched<Dot> dot{};
inline constexpr contact_detail::Dispatched<RowsDot4> rows_dot4{};
inline constexpr contact_detail::Dispatched<SubColumns> sub_columns{};
inline constexpr contact_detail::Dispatched<ComplianceProduct> compliance_product{};

// max |x_i|, NaN if any entry is NaN (as numpy's max of abs).
inline double max_abs(const double* x, std::size_t m) noexcept {
    double r = 0.0;
    for (std::size_t i = 0; i < m; ++i) {
        const double a = std::fabs(x[i]);
        if (a > r || a != a) r = a;
        if (r != r) return r;
    }
    return r;
}

}  // namespace tactile
