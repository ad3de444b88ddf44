// The piece systems of ContactSolverKernel (contact_kernel.hpp): within one piece (a
// fixed classification of the nodes) the contact problem is a linear system over the
// touching nodes' unknowns. Here it is prepared (factor_piece: the base piece's LU
// reused, bordered by the piece's differences, extended by nodes that touched down, or
// refactored), solved (solve_prepared, solve_bordered), and its displacements and affine
// responses to the plate's motion formed (piece_displacement, piece_response).
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "contact_kernel.hpp"

namespace tactile {

inline void ContactSolverKernel::piece_displacement(const double* lam, double* u, bool unit, double az, double ay,
                                                    double plate_z, double ds) noexcept {
    const std::size_t n = n_, n2 = n2_;
    double* pl = disp_.plam.data();
    for (std::size_t i = 0; i < n; ++i) { pl[i] = lam[i]; pl[n + i] = -lam[n + i]; }
    std::size_t* fr = disp_.free_rows.data();
    std::size_t nf = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const std::int8_t s = piece_.state[i];
        if (s == kContactStick) u[i] = unit ? ay : uy_prev_[i] + ds;
        else fr[nf++] = i;
    }
    for (std::size_t i = 0; i < n; ++i) {
        if (piece_.state[i] != kContactOpen) u[n + i] = unit ? az : plate_z - z0_[i];
        else fr[nf++] = n + i;
    }
    // P lam is zero off the touching nodes: the dot products run over the span of
    // its nonzeros in each half (the contact is one run of nodes: its share of the
    // surface)
    std::size_t a0 = n, b0 = 0, a1 = n2, b1 = n;
    for (std::size_t i = 0; i < n; ++i) {
        if (pl[i] != 0.0) { if (i < a0) a0 = i; b0 = i + 1; }
        if (pl[n + i] != 0.0) { if (n + i < a1) a1 = n + i; b1 = n + i + 1; }
    }
    const std::size_t l0 = b0 > a0 ? b0 - a0 : 0, l1 = b1 > a1 ? b1 - a1 : 0;
    std::size_t q = 0;
    const double* C = C_.data();
    double s4[4], t4[4];
    for (; q + 4 <= nf; q += 4) {
        const double *r0 = C + fr[q] * n2, *r1 = C + fr[q + 1] * n2, *r2 = C + fr[q + 2] * n2,
                     *r3 = C + fr[q + 3] * n2;
        s4[0] = s4[1] = s4[2] = s4[3] = t4[0] = t4[1] = t4[2] = t4[3] = 0.0;
        if (l0) rows_dot4(r0 + a0, r1 + a0, r2 + a0, r3 + a0, pl + a0, l0, s4);
        if (l1) rows_dot4(r0 + a1, r1 + a1, r2 + a1, r3 + a1, pl + a1, l1, t4);
        u[fr[q]] = s4[0] + t4[0]; u[fr[q + 1]] = s4[1] + t4[1];
        u[fr[q + 2]] = s4[2] + t4[2]; u[fr[q + 3]] = s4[3] + t4[3];
    }
    for (; q < nf; ++q) {
        const double* r = C + fr[q] * n2;
        u[fr[q]] = (l0 ? dot(r + a0, pl + a0, l0) : 0.0) + (l1 ? dot(r + a1, pl + a1, l1) : 0.0);
    }
}

inline int ContactSolverKernel::factor_piece(const std::int8_t* state, const double* sign) noexcept {
    const std::size_t n = n_;
    for (std::size_t i = 0; i < n; ++i)
        piece_.slip_coef[i] = state[i] == kContactSlip ? act_.mu[i] * sign[i] : 0.0;
    if (base_.valid) {
        bool same = true;
        for (std::size_t i = 0; i < n && same; ++i)
            same = piece_.state[i] == state[i] && piece_.coef[i] == piece_.slip_coef[i];
        if (same) return 0;
        if (update_piece(state) || (extend_base(state) && update_piece(state))) {
            copy8(state, piece_.state.data());
            copy(piece_.slip_coef.data(), piece_.coef.data());
            ++stats_.updates;
            ++piece_.id;
            return 0;
        }
    }
    return refactor_piece(state);
}

inline int ContactSolverKernel::refactor_piece(const std::int8_t* state) noexcept {
    const std::size_t n = n_;
    ++piece_.id;
    base_changing();
    std::size_t m = 0;
    for (std::size_t i = 0; i < n; ++i) base_.pos_ln[i] = base_.pos_lt[i] = -1;
    for (std::size_t i = 0; i < n; ++i)
        if (state[i] != kContactOpen) {
            base_.node[m] = i; base_.kind[m] = 0; base_.pos_ln[i] = static_cast<long>(m++);
        }
    for (std::size_t i = 0; i < n; ++i)
        if (state[i] == kContactStick) {
            base_.node[m] = i; base_.kind[m] = 1; base_.pos_lt[i] = static_cast<long>(m++);
        }
    base_.m = m;
    double* M = base_.M.data();
    // rows: g on the active nodes, then w on the stuck ones; columns: ln_A, lt_T
    for (std::size_t k = 0; k < m; ++k) {
        const double* c = C_.data() + eq_row(k) * n2_;
        double* mk = M + k * n2_;
        for (std::size_t j = 0; j < m; ++j) {
            const std::size_t i = base_.node[j];
            mk[j] = base_.kind[j] ? c[i] : c[i] * piece_.slip_coef[i] - c[n + i];
        }
    }
    ++stats_.factorizations;
    const int info = lu_factor(M, m, n2_, base_.piv.data());
    if (info != 0) return info;
    copy8(state, piece_.state.data());
    copy(piece_.slip_coef.data(), piece_.coef.data());
    copy8(state, base_.state.data());
    copy(piece_.slip_coef.data(), base_.coef.data());
    base_.valid = true;
    ++piece_.id;
    return 0;
}

inline void ContactSolverKernel::solve_prepared(double plate_z, double ds, double* lam, bool unit, double az,
                                                double ay) noexcept {
    const std::size_t n = n_, m = base_.m, nb = border_.n;
    auto rhs_g = [&](std::size_t i) { return unit ? az : plate_z - z0_[i]; };
    auto rhs_w = [&](std::size_t i) { return unit ? ay : uy_prev_[i] + ds; };
    double* b = base_.rhs.data();
    double* c = border_.rhs.data();
    for (std::size_t k = 0; k < m; ++k) b[k] = base_.kind[k] ? rhs_w(base_.node[k]) : rhs_g(base_.node[k]);
    for (std::size_t r = 0; r < nb; ++r) {
        const BorderRow& br = border_.rows[r];
        c[r] = br.kind == kAddG ? rhs_g(br.node) : (br.kind == kAddW ? rhs_w(br.node) : 0.0);
    }
    // the base solve of a unit right-hand side depends on the base only: kept
    // until the next refactorisation, so a unit response of a bordered piece costs
    // O(m nb) besides its compliance product
    const int which = !unit ? -1 : (az == 1.0 && ay == 0.0 ? 0 : (az == 0.0 && ay == 1.0 ? 1 : -1));
    if (which >= 0) {
        double* zc = base_.unit_z.data() + static_cast<std::size_t>(which) * n2_;
        if (!base_.unit_valid[which]) {
            lu_solve(base_.M.data(), m, n2_, base_.piv.data(), b);
            copy(b, zc, m);
            base_.unit_valid[which] = true;
        } else {
            copy(zc, b, m);
        }
        solve_bordered(b, c, lam, true);
    } else {
        solve_bordered(b, c, lam, false);
    }
    (void)n;
}

inline int ContactSolverKernel::piece_response(const std::int8_t* state, const double* sign, double plate_z,
                                               double plate_y, double ds, double* lam, double* u) noexcept {
    const int info = factor_piece(state, sign);
    if (info != 0) return info;
    if (aff_.stage > 0 && aff_.piece == piece_.id && stick_offsets_unchanged()) {
        const double dz = plate_z - aff_.plate_z, dy = plate_y - aff_.plate_y;
        if (aff_.stage == 1 && (dz != 0.0 || dy != 0.0)) {
            solve_prepared(0.0, 0.0, aff_.lam_dz.data(), true, 1.0, 0.0);
            piece_displacement(aff_.lam_dz.data(), aff_.u_dz.data(), true, 1.0, 0.0, 0.0, 0.0);
            solve_prepared(0.0, 0.0, aff_.lam_dy.data(), true, 0.0, 1.0);
            piece_displacement(aff_.lam_dy.data(), aff_.u_dy.data(), true, 0.0, 1.0, 0.0, 0.0);
            aff_.stage = 2;
        }
        if (aff_.stage == 2) {
            for (std::size_t i = 0; i < n2_; ++i) {
                lam[i] = aff_.lam[i] + dz * aff_.lam_dz[i] + dy * aff_.lam_dy[i];
                u[i] = aff_.u[i] + dz * aff_.u_dz[i] + dy * aff_.u_dy[i];
            }
        } else {
            copy(aff_.lam.data(), lam, n2_);
            copy(aff_.u.data(), u, n2_);
        }
        for (std::size_t i = 0; i < n_; ++i)  // exact zeros stay exact
            if (piece_.state[i] == kContactOpen) lam[i] = lam[n_ + i] = 0.0;
        ++stats_.affine;
        return 0;
    }
    solve_prepared(plate_z, ds, lam);
    piece_displacement(lam, u, false, 0.0, 0.0, plate_z, ds);
    copy(lam, aff_.lam.data(), n2_);
    copy(u, aff_.u.data(), n2_);
    aff_.plate_z = plate_z;
    aff_.plate_y = plate_y;
    for (std::size_t i = 0; i < n_; ++i) aff_.stick_offset[i] = uy_prev_[i] - s_prev_;
    aff_.piece = piece_.id;
    aff_.stage = 1;
    return 0;
}

inline void ContactSolverKernel::solve_bordered(double* b, double* c, double* lam, bool base_solved) noexcept {
    const std::size_t n = n_, m = base_.m, nb = border_.n;
    double* z = b;
    if (!base_solved) {
        // The iterations of one point (the active-set steps of a solve, the rounds of a
        // breakaway cascade) border the same base with the same right-hand side: its
        // base solve is kept and reused while both are unchanged (the same bits)
        if (base_.load_valid && std::memcmp(base_.load_rhs.data(), b, m * sizeof(double)) == 0) {
            copy(base_.load_z.data(), z, m);
            ++stats_.rhs_reuses;
        } else {
            copy(b, base_.load_rhs.data(), m);
            lu_solve(base_.M.data(), m, n2_, base_.piv.data(), z);
            copy(z, base_.load_z.data(), m);
            base_.load_valid = true;
        }
    }
    double* y = c;
    if (nb > 0) {  // Schur complement: S y = c - W^T M0^-1 b, x = M0^-1 b - (M0^-1 V) y
        for (std::size_t r = 0; r < nb; ++r) y[r] -= border_row_dot(r, z);
        lu_solve(border_.S_lu.data(), nb, kMaxBorder, border_.piv.data(), y);
        // (the columns' addresses from their slots: a kernel copied from another
        // (a pad's shadow ridge detached from its master) has its own cache)
        for (std::size_t c = 0; c < nb; ++c) border_.vcol[c] = cols_.data.data() + border_.vslot[c] * n2_;
        sub_columns(z, m, border_.vcol.data(), y, nb);
    }
    for (std::size_t i = 0; i < n2_; ++i) lam[i] = 0.0;
    // base unknowns (those fixed to zero by the border come out as ~zero and are
    // overwritten below)
    for (std::size_t k = 0; k < m; ++k) lam[base_.kind[k] ? base_.node[k] : n + base_.node[k]] = z[k];
    for (std::size_t col = 0; col < nb; ++col) {
        const BorderCol& bc = border_.cols[col];
        if (bc.kind == kAddLn) lam[n + bc.node] = y[col];
        else if (bc.kind == kAddLt) lam[bc.node] = y[col];
    }
    for (std::size_t i = 0; i < n; ++i) {
        if (piece_.state[i] == kContactSlip) lam[i] = piece_.coef[i] * lam[n + i];  // lt = mu sign ln
        else if (piece_.state[i] == kContactOpen) lam[i] = lam[n + i] = 0.0;     // exactly, not ~0 from the border
    }
}

inline bool ContactSolverKernel::stick_offsets_unchanged() const noexcept {
    const double tol = 1e-13 * scale_len_;
    for (std::size_t i = 0; i < n_; ++i) {
        if (piece_.state[i] != kContactStick) continue;
        const double v = uy_prev_[i] - s_prev_, ref = aff_.stick_offset[i];
        if (std::fabs(v - ref) > tol) return false;
    }
    return true;
}

inline int ContactSolverKernel::solve_piece(const std::int8_t* state, const double* sign, double plate_z,
                                            double ds, double* lam) noexcept {
    const int info = factor_piece(state, sign);
    if (info != 0) return info;
    solve_prepared(plate_z, ds, lam);
    return 0;
}

// The base factors are about to change (refactor_piece, extend_base): they are not valid
// until the change succeeds, and the border and every solve kept with the old base (the
// M0^-1 V columns, the unit and load right-hand sides' base solves) are forgotten.
inline void ContactSolverKernel::base_changing() noexcept {
    base_.valid = false;
    border_.n = 0;
    cols_.n = 0;
    border_.last_n = 0;
    border_.lu_ok = false;
    base_.unit_valid[0] = base_.unit_valid[1] = false;
    base_.load_valid = false;
}

// Border row r of W^T (border_.Wt) against x (length base_.m). The rows of the force laws are
// zero but at one entry (kFix: the unknown fixed to zero) or two (kSlipRow: lt_i and
// ln_i), so they cost those entries, not a dot product over the base: with the
// slip front moving, most border rows are of this kind, and the dot products were
// a bordered solve's largest cost after its base solve.
inline double ContactSolverKernel::border_row_dot(std::size_t r, const double* x) const noexcept {
    const BorderRow& br = border_.rows[r];
    const double* w = border_.Wt.data() + r * n2_;
    if (br.kind == kFix) return w[br.pos] * x[br.pos];
    if (br.kind == kSlipRow) {
        const std::size_t q = static_cast<std::size_t>(base_.pos_ln[br.node]);
        return w[br.pos] * x[br.pos] + w[q] * x[q];
    }
    return dot(w, x, base_.m);
}

// Border the base for the piece (state, piece_.slip_coef); false if it needs more than
// kMaxBorder borders or its Schur complement is singular (then refactor).
inline bool ContactSolverKernel::update_piece(const std::int8_t* state) noexcept {
    const std::size_t n = n_, m = base_.m;
    std::size_t nr = 0, nc = 0;
    auto add_row = [&](std::uint8_t kind, std::size_t node, std::size_t pos) {
        if (nr < kMaxBorder) border_.rows[nr] = {kind, node, pos};
        ++nr;
    };
    auto add_col = [&](std::uint8_t kind, std::size_t node, std::size_t pos) {
        if (nc < kMaxBorder) border_.cols[nc] = {kind, node, pos};
        ++nc;
    };
    for (std::size_t i = 0; i < n; ++i) {
        const std::int8_t s0 = base_.state[i], s1 = state[i];
        const bool a0 = s0 != kContactOpen, a1 = s1 != kContactOpen;
        const bool t0 = s0 == kContactStick, t1 = s1 == kContactStick;
        if (t0 && s1 == kContactSlip) {  // stuck in the base, sliding now: the slip law as a row
            add_row(kSlipRow, i, static_cast<std::size_t>(base_.pos_lt[i]));
            add_col(kSlack, i, static_cast<std::size_t>(base_.pos_lt[i]));  // w_i is base equation pos_lt
            if (nr > kMaxBorder || nc > kMaxBorder) return false;
            continue;
        }
        const bool same_ln = a0 && a1 && base_.coef[i] == piece_.slip_coef[i];
        if (a0 && !same_ln) add_row(kFix, i, static_cast<std::size_t>(base_.pos_ln[i]));
        if (a1 && !same_ln) add_col(kAddLn, i, 0);
        if (t0 && !t1) add_row(kFix, i, static_cast<std::size_t>(base_.pos_lt[i]));
        if (t1 && !t0) add_col(kAddLt, i, 0);
        if (a0 && !a1) add_col(kSlack, i, static_cast<std::size_t>(base_.pos_ln[i]));  // g_i is base equation pos_ln
        if (a1 && !a0) add_row(kAddG, i, 0);
        if (t0 && !t1) add_col(kSlack, i, static_cast<std::size_t>(base_.pos_lt[i]));  // w_i is base equation pos_lt
        if (t1 && !t0) add_row(kAddW, i, 0);
        if (nr > kMaxBorder || nc > kMaxBorder) return false;
    }
    if (nr != nc) return false;  // cannot happen (both pieces are square); be safe
    const std::size_t nb = nr;
    const std::size_t K = kMaxBorder;
    auto row_coef = [&](const BorderRow& br) { return br.kind == kSlipRow ? piece_.slip_coef[br.node] : 0.0; };
    auto col_coef = [&](const BorderCol& bc) { return bc.kind == kAddLn ? piece_.slip_coef[bc.node] : 0.0; };
    // where a border row (column) of this piece was one of the last piece's, with the
    // same coefficient: its entries are kept (-1: new)
    // (found through per-node chains of the old entries: a node has at most two
    // border rows and two columns, so a lookup is a step or two; a scan of the last
    // border costs a fifth of a bordered update's own time on the open-loop paths)
    long* head = border_.node_head.data();
    auto kept = [&](const auto& b, double coef, const auto& old, const auto& old_coef) -> long {
        for (long q = head[b.node]; q >= 0; q = border_.chain_next[static_cast<std::size_t>(q)])
            if (old[q].kind == b.kind && old[q].pos == b.pos && old_coef[q] == coef) return q;
        return -1;
    };
    link_chains(border_.last_rows.data(), border_.last_n, head, border_.chain_next.data());
    for (std::size_t r = 0; r < nb; ++r)
        border_.row_map[r] = kept(border_.rows[r], row_coef(border_.rows[r]), border_.last_rows, border_.last_row_coef);
    unlink_chains(border_.last_rows.data(), border_.last_n, head);
    link_chains(border_.last_cols.data(), border_.last_n, head, border_.chain_next.data());
    for (std::size_t c = 0; c < nb; ++c)
        border_.col_map[c] = kept(border_.cols[c], col_coef(border_.cols[c]), border_.last_cols, border_.last_col_coef);
    unlink_chains(border_.last_cols.data(), border_.last_n, head);
    // (the rows of the force laws are read at their one or two entries only,
    // border_row_dot: the others are not written)
    // when every row and column of the last border is kept (nodes added to the
    // border, none taken off: a cascade sliding its nodes a few at a time), they
    // go first in their old order and the factors of the last S are extended by
    // the new rows and columns (extend_s), O(nb^2 k) for k new ones instead of O(nb^3)
    std::size_t kept_r = 0, kept_c = 0;
    for (std::size_t r = 0; r < nb; ++r) kept_r += border_.row_map[r] >= 0;
    for (std::size_t c = 0; c < nb; ++c) kept_c += border_.col_map[c] >= 0;
    // (so nb >= border_.last_n)
    const bool extend = border_.lu_ok && border_.last_n > 0 && kept_r == border_.last_n && kept_c == border_.last_n;
    if (extend) {
        std::size_t qr = border_.last_n, qc = border_.last_n;
        for (std::size_t r = 0; r < nb; ++r) {
            const std::size_t d = border_.row_map[r] >= 0 ? static_cast<std::size_t>(border_.row_map[r]) : qr++;
            border_.tmp_rows[d] = border_.rows[r];
        }
        for (std::size_t c = 0; c < nb; ++c) {
            const std::size_t d = border_.col_map[c] >= 0 ? static_cast<std::size_t>(border_.col_map[c]) : qc++;
            border_.tmp_cols[d] = border_.cols[c];
        }
        for (std::size_t r = 0; r < nb; ++r) {
            border_.rows[r] = border_.tmp_rows[r];
            border_.cols[r] = border_.tmp_cols[r];
            border_.row_map[r] = border_.col_map[r] = r < border_.last_n ? static_cast<long>(r) : -1;
        }
    }
    // M0^-1 V: columns already solved for this base (the same border column of an
    // earlier nearby piece) come from the column cache; the others are gathered to
    // the front of border_.vnew and solved together (one pass over the factors for all)
    std::size_t nnew = 0;
    for (std::size_t q = 0; q < kColCache; ++q) cols_.used[q] = 0;
    link_chains(cols_.key.data(), cols_.n, head, cols_.chain_next.data());
    for (std::size_t c = 0; c < nb; ++c) {
        const BorderCol& bc = border_.cols[c];
        const double coef = col_coef(bc);
        std::size_t hit = kColCache;
        for (long q = head[bc.node]; q >= 0; q = cols_.chain_next[static_cast<std::size_t>(q)]) {
            const CachedCol& cc = cols_.key[static_cast<std::size_t>(q)];
            if (cc.kind == bc.kind && cc.pos == bc.pos && cc.coef == coef) { hit = static_cast<std::size_t>(q); break; }
        }
        if (hit < kColCache) {  // the border reads the cached column in place
            border_.vcol[c] = cols_.data.data() + hit * n2_;
            border_.vslot[c] = hit;
            cols_.used[hit] = 1;
            continue;
        }
        double* w = border_.vnew.data() + nnew * n2_;
        for (std::size_t k = 0; k < m; ++k) {
            if (bc.kind == kSlack) w[k] = k == bc.pos ? 1.0 : 0.0;
            else if (bc.kind == kAddLn) w[k] = coef_ln(eq_row(k), bc.node, coef);
            else w[k] = coef_lt(eq_row(k), bc.node);
        }
        border_.new_col[nnew++] = c;
    }
    unlink_chains(cols_.key.data(), cols_.n, head);
    if (nnew > 0) lu_solve(base_.M.data(), m, n2_, base_.piv.data(), border_.vnew.data(), n2_, nnew);
    // the new columns go to free slots of the cache, or replace columns this border
    // does not use (kColCache >= 2 kMaxBorder: there is always one)
    for (std::size_t q = 0; q < nnew; ++q) {
        const std::size_t c = border_.new_col[q];
        const BorderCol& bc = border_.cols[c];
        const double coef = col_coef(bc);
        std::size_t slot;
        if (cols_.n < kColCache) {
            slot = cols_.n++;
        } else {
            do slot = cols_.next_slot++ % kColCache; while (cols_.used[slot]);
        }
        cols_.used[slot] = 1;
        cols_.key[slot] = {bc.kind, bc.node, bc.pos, coef};
        double* v = cols_.data.data() + slot * n2_;
        std::memcpy(v, border_.vnew.data() + q * n2_, m * sizeof(double));
        border_.vcol[c] = v;
        border_.vslot[c] = slot;
    }
    // W^T rows over the base unknowns, and S = Z - W^T (M0^-1 V). The rows of the
    // force laws (kFix: an unknown is zero; kSlipRow: lt - mu s ln = 0) are written
    // in the units of the displacement rows (kAddG, kAddW: rows of C), times 1 / r:
    // the partial pivoting of S compares its rows, and with unit coefficients the
    // force-law rows outweighed the displacement rows by 1 / mean(diag C) (~1e6),
    // so S was factored with pivots chosen by units, not by size. On an extended
    // base (a slip front moving through nodes that touched sliding) that lost up to
    // 1e-9 of the peak force per bordered solve (a fresh factorisation: 1e-14).
    // The reference scales the other way (its displacement rows by r): the same
    // ratio between the two kinds of rows.
    //
    // A border row and column met in the last border of this base (the same kind,
    // node, position and coefficient) keep their W^T row and their entry of S: the
    // pieces of one point (active-set steps, cascade rounds) differ by a few nodes,
    // so only the new rows and columns cost dot products over the base. The entries
    // are the same bits as computed afresh.
    const double law = 1.0 / r_;
    // Extended (every entry of the last border kept, in its place): its W^T rows and
    // the leading border_.last_n x border_.last_n block of S stay where they are, only the new rows of
    // W^T and the new rows and columns of S are written. Else both are rebuilt into
    // the spare buffers, the kept entries copied from their old places.
    const std::size_t r0 = extend ? border_.last_n : 0;
    stats_.border_extensions += extend;
    double* wt = extend ? border_.Wt.data() : border_.Wt_spare.data();
    double* sb = extend ? border_.S.data() : border_.S_spare.data();
    for (std::size_t r = r0; r < nb; ++r) {
        const BorderRow& br = border_.rows[r];
        double* w = wt + r * n2_;
        if (br.kind == kFix) {
            w[br.pos] = law;
        } else if (br.kind == kSlipRow) {  // lt_i - mu s ln_i (ln_i has slip coefficient 0 in the base)
            w[br.pos] = law;
            w[static_cast<std::size_t>(base_.pos_ln[br.node])] = -piece_.slip_coef[br.node] * law;
        } else if (border_.row_map[r] >= 0) {
            std::memcpy(w, border_.Wt.data() + static_cast<std::size_t>(border_.row_map[r]) * n2_, m * sizeof(double));
        } else {
            const std::size_t row = br.kind == kAddG ? n + br.node : br.node;
            for (std::size_t k = 0; k < m; ++k) w[k] = base_coef(row, k);
        }
    }
    if (!extend) border_.Wt.swap(border_.Wt_spare);
    for (std::size_t r = 0; r < nb; ++r) {
        const BorderRow& br = border_.rows[r];
        double* srow = sb + r * K;
        const double* orow =
            border_.row_map[r] >= 0 ? border_.S.data() + static_cast<std::size_t>(border_.row_map[r]) * K : nullptr;
        for (std::size_t c = r < r0 ? r0 : 0; c < nb; ++c) {
            if (orow && border_.col_map[c] >= 0) {
                srow[c] = orow[border_.col_map[c]];
                continue;
            }
            const BorderCol& bc = border_.cols[c];
            double z = 0.0;
            if (br.kind != kFix && br.kind != kSlipRow && bc.kind != kSlack) {
                const std::size_t row = br.kind == kAddG ? n + br.node : br.node;
                z = bc.kind == kAddLn ? coef_ln(row, bc.node, piece_.slip_coef[bc.node]) : coef_lt(row, bc.node);
            }
            srow[c] = z - border_row_dot(r, border_.vcol[c]);
        }
    }
    if (!extend) border_.S.swap(border_.S_spare);
    const std::size_t nb0 = border_.last_n;
    for (std::size_t r = 0; r < nb; ++r) {
        border_.last_rows[r] = border_.rows[r];
        border_.last_row_coef[r] = row_coef(border_.rows[r]);
        border_.last_cols[r] = border_.cols[r];
        border_.last_col_coef[r] = col_coef(border_.cols[r]);
    }
    border_.last_n = nb;
    border_.n = nb;
    const bool ok = extend ? extend_s(nb0, nb) : factor_s(nb);
    border_.lu_ok = ok;
    if (!ok) border_.n = 0;
    return ok;
}

// LU of the border's Schur complement border_.S (nb square, ld kMaxBorder) into border_.S_lu.
inline bool ContactSolverKernel::factor_s(std::size_t nb) noexcept {
    const std::size_t K = kMaxBorder;
    for (std::size_t r = 0; r < nb; ++r) copy(border_.S.data() + r * K, border_.S_lu.data() + r * K, nb);
    return nb == 0 || lu_factor(border_.S_lu.data(), nb, K, border_.piv.data()) == 0;
}

// border_.S_lu holds the factors of border_.S's leading nb0 x nb0 block (the last border's S):
// extend them to all of border_.S (nb square), as extend_base extends the base: with
// P0 S00 = L0 U0, the new columns through P0 and L0 (Y), the new rows through U0
// (X), and the LU of Z - X Y with partial pivoting within the new block.
inline bool ContactSolverKernel::extend_s(std::size_t nb0, std::size_t nb) noexcept {
    const std::size_t K = kMaxBorder, k = nb - nb0;
    if (k == 0) return true;
    double* S = border_.S_lu.data();
    const double* S0 = border_.S.data();
    double* t = border_.vnew.data();  // the new columns, column-major (ld K)
    for (std::size_t c = 0; c < k; ++c)
        for (std::size_t r = 0; r < nb0; ++r) t[c * K + r] = S0[r * K + nb0 + c];
    if (nb0 > 0) lu_forward(S, nb0, K, border_.piv.data(), t, K, k);
    for (std::size_t c = 0; c < k; ++c)
        for (std::size_t r = 0; r < nb0; ++r) S[r * K + nb0 + c] = t[c * K + r];
    for (std::size_t r = nb0; r < nb; ++r) copy(S0 + r * K, S + r * K, nb);
    if (nb0 > 0) lu_right_upper(S, nb0, K, S + nb0 * K, K, k);
    return finish_extension(S, K, nb0, k, border_.piv.data());
}

// The last step of extending an LU (P0 A00 = L0 U0, leading m0 x m0 of A, ld lda) by k
// rows and columns, as extend_base and extend_s do: A's new rows hold X (through U0)
// left of the new block and Z in it, its new columns Y (through P0 and L0) above it.
// S = Z - X Y goes into the new block, then its LU with partial pivoting within the
// block (pivots piv[m0..m0+k), offset to whole rows); its row swaps apply to X too.
inline bool ContactSolverKernel::finish_extension(double* A, std::size_t lda, std::size_t m0, std::size_t k,
                                                  int* piv) noexcept {
    for (std::size_t r = m0; r < m0 + k; ++r) {
        double* ar = A + r * lda;
        for (std::size_t q = 0; q < m0; ++q) {
            const double a = ar[q];
            if (a == 0.0) continue;
            const double* yq = A + q * lda + m0;
            for (std::size_t c = 0; c < k; ++c) ar[m0 + c] -= a * yq[c];
        }
    }
    int* ps = piv + m0;
    if (lu_factor(A + m0 * lda + m0, k, lda, ps) != 0) return false;
    for (std::size_t q = 0; q < k; ++q) {
        const std::size_t p = static_cast<std::size_t>(ps[q]);
        if (p != q) {
            double* a = A + (m0 + q) * lda;
            double* b = A + (m0 + p) * lda;
            for (std::size_t j = 0; j < m0; ++j) { const double h = a[j]; a[j] = b[j]; b[j] = h; }
        }
        ps[q] = static_cast<int>(m0 + p);
    }
    return true;
}

// Append to the base the nodes the piece (state, piece_.slip_coef) touches and the base
// leaves open (the contact growing under the press, a node touching down), their
// ln (and lt, if stuck) as new unknowns and g (and w) as new equations, when the
// piece's other differences then fit a border; false if there is nothing to append,
// they do not fit, or the appended block is singular (then the caller refactors).
//
// With P0 M0 = L0 U0 the factors of the base, the extended matrix [M0 V; W^T Z]
// has the factors L = [L0 0; Ps X Ls], U = [U0 Y; 0 Us] with Y = L0^-1 P0 V,
// X = W^T U0^-1 and Ps (Z - X Y) = Ls Us (partial pivoting within the new block):
// O(nb m^2) for nb new positions, where refactoring costs O(m^3). This is the
// bordered system's own Schur complement, kept as part of the base; the growing
// contact of a press is then factored once instead of once per kMaxBorder / 2
// nodes.
inline bool ContactSolverKernel::extend_base(const std::int8_t* state) noexcept {
    const std::size_t n = n_, n2 = n2_, m = base_.m;
    std::size_t rows = 0, add = 0;  // border rows of the other differences; positions to append
    for (std::size_t i = 0; i < n; ++i) {
        const std::int8_t s0 = base_.state[i], s1 = state[i];
        const bool a0 = s0 != kContactOpen, a1 = s1 != kContactOpen;
        const bool t0 = s0 == kContactStick, t1 = s1 == kContactStick;
        if (!a0 && a1) { add += t1 ? 2 : 1; continue; }
        if (t0 && s1 == kContactSlip) { ++rows; continue; }
        const bool same_ln = a0 && a1 && base_.coef[i] == piece_.slip_coef[i];
        rows += (a0 && !same_ln) + (t0 && !t1) + (t1 && !t0);
    }
    if (add == 0 || rows > kMaxBorder) return false;
    const std::size_t me = m + add;
    for (std::size_t i = 0, q = m; i < n; ++i) {
        if (base_.state[i] != kContactOpen || state[i] == kContactOpen) continue;
        base_.node[q] = i; base_.kind[q] = 0; base_.pos_ln[i] = static_cast<long>(q++);
        if (state[i] == kContactStick) {
            base_.node[q] = i; base_.kind[q] = 1; base_.pos_lt[i] = static_cast<long>(q++);
        }
        base_.state[i] = state[i];
        base_.coef[i] = piece_.slip_coef[i];
    }
    // from here on the base is changed: a failure must refactor
    base_changing();
    double* M = base_.M.data();
    // Y: the new columns over the base equations, through P0 and L0, in chunks of
    // kMaxBorder columns gathered into border_.vnew
    for (std::size_t c0 = m; c0 < me; c0 += kMaxBorder) {
        const std::size_t kc = me - c0 < kMaxBorder ? me - c0 : kMaxBorder;
        for (std::size_t c = 0; c < kc; ++c) {
            double* v = border_.vnew.data() + c * n2;
            for (std::size_t k = 0; k < m; ++k) v[k] = base_coef(eq_row(k), c0 + c);
        }
        lu_forward(M, m, n2, base_.piv.data(), border_.vnew.data(), n2, kc);
        for (std::size_t c = 0; c < kc; ++c) {
            const double* v = border_.vnew.data() + c * n2;
            for (std::size_t k = 0; k < m; ++k) M[k * n2 + c0 + c] = v[k];
        }
    }
    // X: the new equations over the base unknowns, through U0 (rows m..me-1)
    for (std::size_t r = m; r < me; ++r) {
        const std::size_t row = eq_row(r);
        double* x = M + r * n2;
        for (std::size_t k = 0; k < m; ++k) x[k] = base_coef(row, k);
    }
    lu_right_upper(M, m, n2, M + m * n2, n2, add);
    // Z into the new block; S = Z - X Y, its LU and its row swaps in finish_extension
    for (std::size_t r = m; r < me; ++r) {
        const std::size_t row = eq_row(r);
        double* sr = M + r * n2 + m;
        for (std::size_t c = 0; c < add; ++c) sr[c] = base_coef(row, m + c);
    }
    if (!finish_extension(M, n2, m, add, base_.piv.data())) return false;
    base_.m = me;
    base_.valid = true;
    ++stats_.extensions;
    ++piece_.id;
    return true;
}

}  // namespace tactile
