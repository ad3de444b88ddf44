// The event-driven path following of ContactSolverKernel (contact_kernel.hpp): follow
// and its segments from event to event (first_event, apply_events), the status-cycle
// guard of a load point, the breakaway cascade, and the solves at one load point (the
// active-set iteration solve_load with its Alart-Curnier classification, and the
// damped Newton fallback).
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>

#include "contact_kernel.hpp"

namespace tactile {

inline ContactStatus ContactSolverKernel::follow(const double* ys, const double* zs, std::size_t N, bool every,
                                                 double* lam_out, double* u_out, std::int8_t* state_out,
                                                 std::size_t out_stride2, std::size_t out_stride1) noexcept {
    err_.info = 0; err_.residual = 0.0; err_.atol = 0.0;
    for (std::size_t k = 0; k < N; ++k) {
        // (NaN fails the comparison too)
        if (!(std::fabs(ys[k]) <= kMaxPlatePosition && std::fabs(zs[k]) <= kMaxPlatePosition)) {
            err_.info = static_cast<long>(k);
            return ContactStatus::non_finite_position;
        }
    }
    save();
    if (N) pristine_ = false;
    out_.lam = lam_out; out_.u = u_out; out_.state = state_out;
    out_.stride2 = out_stride2; out_.stride1 = out_stride1;
    if (N && !has_z_) {  // first placement: from above, no lower than the crown
        s_prev_ = ys[0];
        z_prev_ = zs[0] > z0_max_ ? zs[0] : z0_max_;
        has_z_ = true;
    }
    if (N) {
        const ContactStatus s = settle_friction();
        if (s != ContactStatus::ok) {
            restore();
            return s;
        }
    }
    std::size_t k = 0;
    while (k < N) {
        const std::size_t end = every ? k + 1 : segment_end(ys, zs, N, k);
        const std::size_t L = end - k;
        out_.row0 = k;
        // a segment of several samples: the end of each piece by a direct solve (its
        // own accuracy, not the unit responses' extrapolated over the segment)
        const ContactStatus s =
            follow_segment(ys[end - 1], zs[end - 1], L, 1e-9 / static_cast<double>(L), every || L > 1, every);
        if (s != ContactStatus::ok) {
            restore();
            return s;
        }
        k = end;
    }
    return ContactStatus::ok;
}

inline std::size_t ContactSolverKernel::segment_end(const double* ys, const double* zs, std::size_t N,
                                                    std::size_t k) const noexcept {
    const double y0 = k == 0 ? s_prev_ : ys[k - 1], z0 = k == 0 ? z_prev_ : zs[k - 1];
    const double dy = ys[k] - y0, dz = zs[k] - z0;
    const double tol = 1e-9 * std::fmax(std::fabs(dy), std::fabs(dz));
    std::size_t end = k + 1;
    while (end < N) {
        if (!(std::fabs((ys[end] - ys[end - 1]) - dy) <= tol && std::fabs((zs[end] - zs[end - 1]) - dz) <= tol))
            return end;
        ++end;
    }
    return N;
}

// rows [a, b) of the current segment's outputs: the state (lam_c, u_c) (f == null)
// or lam_c + f (lam1 - lam_c) with f = (theta_k - th) / (1 - th)
inline void ContactSolverKernel::fill_rows(std::size_t a, std::size_t b, const double* lc, const double* uc,
                                           const double* l1, const double* u1, double th, std::size_t L) noexcept {
    const std::size_t n2 = n2_;
    if (a >= b) return;
    double frac = 0.0;
    std::int8_t flags = 0;
    if (out_.extra.proj) {  // P lc and P (l1 - lc), once for the rows
        const std::size_t q = out_.q;
        double* pc = out_.pc.data();
        double* pd = out_.pd.data();
        for (std::size_t c = 0; c < q; ++c) pc[c] = pd[c] = 0.0;
        for (std::size_t j = 0; j < n2; ++j) {
            const double* col = out_.Pt.data() + j * q;
            const double x = lc[j], d = l1 ? l1[j] - lc[j] : 0.0;
            if (x != 0.0) for (std::size_t c = 0; c < q; ++c) pc[c] += col[c] * x;
            if (d != 0.0) for (std::size_t c = 0; c < q; ++c) pd[c] += col[c] * d;
        }
    }
    if (out_.extra.frac || out_.extra.flags) {
        report(lc, state_.data(), nullptr, frac);
        bool touch = false, stick = false;
        for (std::size_t i = 0; i < n_; ++i) {
            touch |= state_[i] != kContactOpen;
            stick |= state_[i] == kContactStick;
        }
        flags = static_cast<std::int8_t>((touch ? 1 : 0) | (touch && !stick ? 2 : 0));
    }
    for (std::size_t k = a; k < b; ++k) {
        const std::size_t row = out_.row0 + k;
        double f = 0.0;
        if (l1) f = (static_cast<double>(k + 1) / static_cast<double>(L) - th) / (1.0 - th);
        if (out_.extra.proj) {
            double* o = out_.extra.proj + row * out_.extra.stride_q;
            for (std::size_t c = 0; c < out_.q; ++c) o[c] = out_.pc[c] + f * out_.pd[c];
        }
        if (out_.extra.frac) out_.extra.frac[row * out_.extra.stride_f] = frac;
        if (out_.extra.flags) out_.extra.flags[row * out_.extra.stride_f] = flags;
        if (out_.lam) {
            double* o = out_.lam + row * out_.stride2;
            if (l1) for (std::size_t i = 0; i < n2; ++i) o[i] = lc[i] + f * (l1[i] - lc[i]);
            else copy(lc, o, n2);
        }
        if (out_.u) {
            double* o = out_.u + row * out_.stride2;
            if (l1) for (std::size_t i = 0; i < n2; ++i) o[i] = uc[i] + f * (u1[i] - uc[i]);
            else copy(uc, o, n2);
        }
        if (out_.state) copy8(state_.data(), out_.state + row * out_.stride1);
    }
}

// Responses (rs, us) to a unit plate displacement along y and (rz, uz) to a unit
// rise of the plate for the current statuses, kept while they and mu do not change.
inline int ContactSolverKernel::unit_response() noexcept {
    const std::size_t n = n_;
    if (unit_.valid && unit_.mu == params.mu && unit_.mu_kinetic == params.mu_kinetic) {
        bool same = true;
        for (std::size_t i = 0; i < n && same; ++i) same = unit_.state[i] == state_[i] && unit_.sign[i] == sign_[i];
        if (same) return 0;
    }
    unit_.valid = false;
    set_path_cones();
    const int info = factor_piece(state_.data(), sign_.data());
    if (info != 0) return info;
    solve_prepared(0.0, 0.0, unit_.lam_dy.data(), true, 0.0, 1.0);
    solve_prepared(0.0, 0.0, unit_.lam_dz.data(), true, 1.0, 0.0);
    piece_displacement(unit_.lam_dy.data(), unit_.u_dy.data(), true, 0.0, 1.0, 0.0, 0.0);
    piece_displacement(unit_.lam_dz.data(), unit_.u_dz.data(), true, 1.0, 0.0, 0.0, 0.0);
    copy8(state_.data(), unit_.state.data()); copy(sign_.data(), unit_.sign.data());
    unit_.mu = params.mu; unit_.mu_kinetic = params.mu_kinetic;
    unit_.valid = true;
    ++solves_;
    return 0;
}

// A status change at the current point (the reference's _changed): counted; if
// the statuses return to a set already met at this point, all of them are decided
// together by resolve_point; a second return is a cycle (status_cycle).
inline ContactStatus ContactSolverKernel::changed(double tiny_y, double tiny_z) noexcept {
    ++events_;
    std::int8_t* key = ev_.key.data();
    encode_statuses(key);
    if (!seen_has(key, false)) {
        if (!seen_add(key, false)) return cycle_error();
        return ContactStatus::ok;
    }
    if (seen_has(key, true)) return cycle_error();
    const ContactStatus s = resolve_point(tiny_y, tiny_z);
    if (s != ContactStatus::ok) return s;
    encode_statuses(key);
    if (!seen_add(key, true) || !seen_add(key, false)) return cycle_error();
    return ContactStatus::ok;
}

// The start of a solve at the current point with the plate face at zp: statuses and
// signs back to the accepted ones, the path's cones, the length scale of the
// tolerance, and the working classification copied from the accepted one. Returns
// the absolute tolerance of the Alart-Curnier residual.
inline double ContactSolverKernel::begin_point_solve(double zp) noexcept {
    copy8(state_.data(), act_.prev_state.data());
    copy(sign_.data(), act_.prev_sign.data());
    set_path_cones();
    set_scale_len(zp);
    copy8(state_.data(), act_.state.data());
    copy(sign_.data(), act_.sign.data());
    return params.tol * (r_ * scale_len_);
}

// The length scale of a solve with the plate face at zp: the indent, or the largest
// tangential displacement (at least 1e-9 m).
inline void ContactSolverKernel::set_scale_len(double zp) noexcept {
    double uy_max = 0.0;
    for (std::size_t i = 0; i < n_; ++i) {  // (a NaN is skipped, as by fmax)
        const double a = std::fabs(uy_prev_[i]);
        if (a > uy_max) uy_max = a;
    }
    double scale_len = z0_max_ - zp;
    if (1e-9 > scale_len) scale_len = 1e-9;
    if (uy_max > scale_len) scale_len = uy_max;
    scale_len_ = scale_len;
}

// Statuses at the current point from the Alart-Curnier solve of the step (tiny_y,
// tiny_z) ahead, 1e-6 of a sample (cones: kinetic on SLIP nodes, static on the
// others); the state stays at the current point (the reference's _resolve_point).
inline ContactStatus ContactSolverKernel::resolve_point(double tiny_y, double tiny_z) noexcept {
    const std::size_t n = n_;
    const double sc = s_prev_, zc = z_prev_;
    const double ds = tiny_y, zp = zc + tiny_z;
    const double atol = begin_point_solve(zp);
    std::int8_t* st = act_.state.data();
    double* sg = act_.sign.data();
    int it = 0;
    const ContactStatus s = solve_load(st, sg, zp, sc + ds, ds, atol, it, true);
    if (s != ContactStatus::ok) { err_.y = sc + ds; err_.z = zp; return s; }
    ++solves_;
    const double* u = solved_.u.data();
    for (std::size_t i = 0; i < n; ++i) {
        const std::int8_t cs = solved_.state[i], p = act_.prev_state[i];
        const double gap = zp - (z0_[i] + u[n + i]);
        const bool grazing = cs == kContactOpen && p != kContactOpen && gap <= g_tol_;
        const std::int8_t ns = grazing ? p : cs;
        state_[i] = ns;
        sign_[i] = ns == kContactSlip ? (cs == kContactSlip ? solved_.sign[i] : act_.prev_sign[i]) : 0.0;
        sliding_[i] = ns == kContactSlip;
    }
    return ContactStatus::ok;
}

// direct: the end of each piece by a solve of the piece for it; affine (every): that
// solve served by piece_response, O(n) once the piece is met a third time with the
// same stick offsets (see follow).
inline ContactStatus ContactSolverKernel::follow_segment(double s1, double z1, std::size_t L, double eps,
                                                         bool direct, bool affine) noexcept {
    const std::size_t n = n_, n2 = n2_;
    const double s0 = s_prev_, z0p = z_prev_;
    double th = 0.0;
    std::size_t j = 0;
    const std::size_t ns = L;
    ev_.n_seen = 0;  // status sets met at the current point
    const double tiny_y = 1e3 * eps * (s1 - s0), tiny_z = 1e3 * eps * (z1 - z0p);  // 1e-6 of a sample
    if (s1 == s0 && z1 == z0p) {  // the load does not move: nothing slides
        bool any = false;
        for (std::size_t i = 0; i < n; ++i) any |= state_[i] == kContactSlip;
        if (any) {
            for (std::size_t i = 0; i < n; ++i) {
                if (state_[i] == kContactSlip) state_[i] = kContactStick;
                sign_[i] = 0.0;
                sliding_[i] = 0;
            }
            ++events_;
        }
        fill_rows(0, ns, lam_.data(), pu_.data(), nullptr, nullptr, 0.0, L);
        return ContactStatus::ok;
    }
    double* l1 = ev_.lam_end.data();
    double* u1 = ev_.u_end.data();
    while (true) {
        if (th >= 1.0) {
            fill_rows(j, ns, lam_.data(), pu_.data(), nullptr, nullptr, 0.0, L);
            return ContactStatus::ok;
        }
        const double sc = s_prev_, zc = z_prev_;
        const double* lc = lam_.data();
        const double* uc = pu_.data();
        bool any_active = false, any_lam = false;
        for (std::size_t i = 0; i < n; ++i) any_active |= state_[i] != kContactOpen;
        for (std::size_t i = 0; i < n2; ++i) any_lam |= lc[i] != 0.0;
        if (!any_active && !any_lam) {  // nothing touches: the ridge stays at rest
            copy(lc, l1, n2); copy(uc, u1, n2);
        } else if (direct) {
            set_path_cones();
            int info;
            if (affine) {
                set_scale_len(z1);
                info = piece_response(state_.data(), sign_.data(), z1, s1, s1 - sc, l1, u1);
            } else {
                info = factor_piece(state_.data(), sign_.data());
                if (info == 0) {
                    solve_prepared(z1, s1 - sc, l1);
                    piece_displacement(l1, u1, false, 0.0, 0.0, z1, s1 - sc);
                }
            }
            if (info != 0) { err_.info = info; return ContactStatus::singular_piece; }
            ++solves_;
        } else {
            const int info = unit_response();
            if (info != 0) { err_.info = info; return ContactStatus::singular_piece; }
            const double ds = s1 - sc, dz = z1 - zc;
            for (std::size_t i = 0; i < n2; ++i) {
                l1[i] = lc[i] + ds * unit_.lam_dy[i] + dz * unit_.lam_dz[i];
                u1[i] = uc[i] + ds * unit_.u_dy[i] + dz * unit_.u_dz[i];
            }
        }
        // a sliding node whose slip over the rest of the segment does not oppose its
        // friction force sticks here
        {
            const double lim = -1e-9 * (std::fabs(s1 - sc) + std::fabs(z1 - zc));
            std::size_t bad = 0;
            for (std::size_t i = 0; i < n; ++i) {
                if (state_[i] != kContactSlip) continue;
                const double rate = (u1[i] - uc[i]) - (s1 - sc);
                if (sign_[i] * rate >= lim) {
                    state_[i] = kContactStick; sign_[i] = 0.0; sliding_[i] = 0;
                    ++bad;
                }
            }
            if (bad) {
                const ContactStatus s = changed(tiny_y, tiny_z);
                if (s != ContactStatus::ok) return s;
                continue;
            }
        }
        std::size_t n_ev = 0;
        const double frac = first_event(lc, uc, l1, u1, zc, z1, eps / (1.0 - th), n_ev);
        const bool none = n_ev == 0;
        const double th_e = none ? INFINITY : th + frac * (1.0 - th);
        // samples before the event come from this piece
        std::size_t j2 = j;
        while (j2 < ns && static_cast<double>(j2 + 1) / static_cast<double>(L) < th_e - eps) ++j2;
        if (j2 > j) fill_rows(j, j2, lc, uc, l1, u1, th, L);
        j = j2;
        if (none) {
            copy(l1, lam_.data(), n2); copy(u1, pu_.data(), n2); copy(u1, uy_prev_.data());
            s_prev_ = s1; z_prev_ = z1;
            if (j < ns) fill_rows(j, ns, lam_.data(), pu_.data(), nullptr, nullptr, 0.0, L);
            return ContactStatus::ok;
        }
        const double te = th_e < 1.0 ? th_e : 1.0;
        const double f = (te - th) / (1.0 - th);
        for (std::size_t i = 0; i < n2; ++i) {
            lam_[i] = lc[i] + f * (l1[i] - lc[i]);
            pu_[i] = uc[i] + f * (u1[i] - uc[i]);
        }
        copy(pu_.data(), uy_prev_.data());
        s_prev_ = te < 1.0 ? s0 + te * (s1 - s0) : s1;
        z_prev_ = te < 1.0 ? z0p + te * (z1 - z0p) : z1;
        if (te > th) ev_.n_seen = 0;
        th = te;
        std::size_t count = 0;
        ContactStatus s = apply_events(n_ev, count);
        if (s != ContactStatus::ok) return s;
        s = changed(tiny_y, tiny_z);
        if (s != ContactStatus::ok) return s;
    }
}

// First point frac in [0, 1 + eps] of the piece (lc, uc) -> (l1, u1) where a node's
// status must change; the events there go to ev_.node / ev_.kind (kind 0 contact, 1
// separation, 2 / 3 breakaway with the friction force along +y / -y), kind-major as
// the reference orders them. n_ev = 0: none.
inline double ContactSolverKernel::first_event(const double* lc, const double* uc, const double* l1,
                                               const double* u1, double zc, double z1, double eps,
                                               std::size_t& n_ev) noexcept {
    const std::size_t n = n_;
    const double mu = params.mu, tg = evt_g_tol_, tf = evt_f_tol_;
    // one pass over the nodes (each node's status decides which of its functions
    // count), the crossings of kind k at ev_.frac[k n + i], INFINITY where none
    auto cross = [](double pc, double p1, double tol) {
        const double drop = pc - p1;
        return drop > tol && p1 < 0 ? (pc > 0.0 ? pc : 0.0) / drop : INFINITY;
    };
    double* f0 = ev_.frac.data();
    double *f1 = f0 + n, *f2 = f1 + n, *f3 = f2 + n;
    double first = INFINITY;
    for (std::size_t i = 0; i < n; ++i) {
        const std::int8_t s = state_[i];
        double a = INFINITY, b = INFINITY, c = INFINITY, d = INFINITY;
        if (s == kContactOpen) {
            a = cross(zc - z0_[i] - uc[n + i], z1 - z0_[i] - u1[n + i], tg);
        } else {
            const double lnc = lc[n + i], ln1 = l1[n + i];
            b = cross(lnc, ln1, tf);
            if (s == kContactStick) {
                c = cross(mu * lnc - lc[i], mu * ln1 - l1[i], tf);
                d = cross(mu * lnc + lc[i], mu * ln1 + l1[i], tf);
            }
        }
        f0[i] = a; f1[i] = b; f2[i] = c; f3[i] = d;
        const double ab = b < a ? b : a, cd = d < c ? d : c;  // no NaN here (cross)
        const double m = cd < ab ? cd : ab;
        if (m < first) first = m;
    }
    n_ev = 0;
    if (!(first <= 1.0 + eps)) return first;
    for (std::size_t q = 0; q < 4 * n; ++q) {
        if (ev_.frac[q] <= first + eps) {
            ev_.kind[n_ev] = static_cast<std::int8_t>(q / n);
            ev_.node[n_ev] = q % n;
            ++n_ev;
        }
    }
    return first;
}

inline ContactStatus ContactSolverKernel::apply_events(std::size_t n_ev, std::size_t& changes) noexcept {
    const std::size_t n = n_;
    double broke_ln = -INFINITY;
    bool any_broke = false;
    for (std::size_t e = 0; e < n_ev; ++e) {
        const std::size_t i = ev_.node[e];
        const int kind = ev_.kind[e];
        if (kind == 0) { state_[i] = kContactStick; sign_[i] = 0.0; }
        else if (kind == 1) {
            // the displacements at the event point are the piece's (pu_, C P lam_ to
            // round-off); a node lifting off sheds what it still carried (zero to
            // the event tolerance): its columns of C P come off them, O(n) instead
            // of the whole product
            const double dt = -lam_[i], dn = lam_[n + i];  // the change of P lam
            const double* ct = C_.data() + i * n2_;
            const double* cn = C_.data() + (n + i) * n2_;
            if (dt != 0.0 || dn != 0.0)
                for (std::size_t j = 0; j < n2_; ++j) pu_[j] += ct[j] * dt + cn[j] * dn;
            state_[i] = kContactOpen; sign_[i] = 0.0; lam_[i] = lam_[n + i] = 0.0;
        }
        else { state_[i] = kContactSlip; sign_[i] = kind == 2 ? 1.0 : -1.0; }
    }
    for (std::size_t e = 0; e < n_ev; ++e) {  // pressures after all of this point's changes
        if (ev_.kind[e] >= 2) {
            any_broke = true;
            const double ln = lam_[n + ev_.node[e]];
            if (ln > broke_ln) broke_ln = ln;
        }
    }
    for (std::size_t i = 0; i < n; ++i) sliding_[i] = state_[i] == kContactSlip;
    copy(pu_.data(), uy_prev_.data());
    changes = n_ev;
    if (any_broke && (params.mu - params.mu_kinetic) * broke_ln > f_tol_) {
        std::size_t more = 0;
        const ContactStatus s = cascade(more);
        if (s != ContactStatus::ok) return s;
        changes += more;
    }
    return ContactStatus::ok;
}

// A change of the friction coefficients (params, set between calls) is an event at the
// current load: the state was solved with the old cones, so the nodes now beyond their
// static cone break away, the sliding ones drop to the new kinetic cone, and what they
// shed is carried at that same load (the breakaway cascade), before the path goes on.
// Without it a load that stands still (or moves so as to unload those nodes) would keep
// tractions the new friction cannot carry. The reference's _settle_friction.
inline ContactStatus ContactSolverKernel::settle_friction() noexcept {
    if (fr_mu_ == params.mu && fr_muk_ == params.mu_kinetic) return ContactStatus::ok;
    bool touching = false;
    for (std::size_t i = 0; i < n_ && !touching; ++i) touching = state_[i] != kContactOpen;
    if (touching && has_z_) {
        std::size_t changes = 0;
        const ContactStatus s = cascade(changes);
        if (s != ContactStatus::ok) return s;
        if (changes) ++events_;
        unit_.valid = false;
        aff_.stage = 0;
    }
    fr_mu_ = params.mu; fr_muk_ = params.mu_kinetic;
    return ContactStatus::ok;
}

// The breakaway cascade at the current load (the reference's _cascade).
inline ContactStatus ContactSolverKernel::cascade(std::size_t& changes) noexcept {
    const std::size_t n = n_;
    const double mu_k = params.mu_kinetic;
    const double zp = z_prev_, sp = s_prev_;
    const double atol = begin_point_solve(zp);
    std::int8_t* st = act_.state.data();
    double* sg = act_.sign.data();
    for (std::size_t round = 0; round <= n; ++round) {
        int it = 0;
        const ContactStatus s = solve_load(st, sg, zp, sp, 0.0, atol, it, true);
        if (s != ContactStatus::ok) { err_.y = sp; err_.z = zp; return s; }
        ++solves_;
        bool broke = false;
        for (std::size_t i = 0; i < n; ++i) {
            const bool moving = std::fabs(solved_.u[i] - uy_prev_[i]) > w_tol_;
            if (solved_.state[i] == kContactSlip && moving && act_.mu[i] > mu_k) { act_.mu[i] = mu_k; broke = true; }
        }
        if (!broke) break;
        st = act_.state.data(); sg = act_.sign.data();
        copy8(solved_.state.data(), st); copy(solved_.sign.data(), sg);
    }
    const double* lam = solved_.lam.data();
    const double* u = solved_.u.data();
    changes = 0;
    for (std::size_t i = 0; i < n; ++i) {
        const bool moving = std::fabs(u[i] - uy_prev_[i]) > w_tol_;
        const bool on_kinetic = std::fabs(lam[i]) >= mu_k * lam[n + i] - f_tol_;
        const std::int8_t s = solved_.state[i], p = act_.prev_state[i];
        const bool slide_moved = s == kContactSlip && moving;
        const bool slide_kept = p == kContactSlip && s != kContactOpen && !moving && on_kinetic;
        const double gap = zp - (z0_[i] + u[n + i]);
        const bool grazing = s == kContactOpen && p != kContactOpen && gap <= g_tol_;
        std::int8_t ns = s == kContactOpen ? static_cast<std::int8_t>(kContactOpen)
                                           : (slide_moved || slide_kept ? static_cast<std::int8_t>(kContactSlip)
                                                                        : static_cast<std::int8_t>(kContactStick));
        double nsg = slide_moved ? solved_.sign[i] : (slide_kept ? act_.prev_sign[i] : 0.0);
        if (grazing) { ns = p; nsg = act_.prev_sign[i]; }
        changes += ns != p;
        state_[i] = ns;
        sign_[i] = nsg;
        sliding_[i] = ns == kContactSlip;
    }
    copy(lam, lam_.data(), n2_);
    copy(u, pu_.data(), n2_);
    copy(u, uy_prev_.data());
    return ContactStatus::ok;
}

inline ContactStatus ContactSolverKernel::solve_load(std::int8_t* st, double* sg, double plate_z, double plate_y,
                                                     double ds, double atol, int& it, bool exact) noexcept {
    const std::size_t n = n_;
    it = 0;
    std::int8_t* nst = act_.next_state.data();
    double* nsg = act_.next_sign.data();
    bool have_first = false;
    for (int k = 1; k <= params.max_active_set_iter; ++k) {
        it = k;
        const int info = piece_response(st, sg, plate_z, plate_y, ds, solved_.lam.data(), solved_.u.data());
        if (info != 0) { err_.info = info; return ContactStatus::singular_piece; }
        const double fmax = classify(solved_.lam.data(), solved_.u.data(), plate_z, ds, act_.F.data(), nst, nsg);
        bool same = true;
        for (std::size_t i = 0; i < n && same; ++i)
            same = nst[i] == st[i] && (st[i] != kContactSlip || nsg[i] == sg[i]);
        if (fmax <= atol) {
            if (!exact || same) {
                copy8(nst, solved_.state.data()); copy(nsg, solved_.sign.data());
                return ContactStatus::ok;
            }
            if (!have_first) {
                copy(solved_.lam.data(), act_.first_lam.data(), n2_); copy(solved_.u.data(), act_.first_u.data(), n2_);
                copy8(nst, act_.first_state.data()); copy(nsg, act_.first_sign.data());
                have_first = true;
            }
        } else if (same) {
            break;  // same piece but not converged: round-off trouble, use Newton
        }
        std::int8_t* ts = st; st = nst; nst = ts;
        double* tg = sg; sg = nsg; nsg = tg;
    }
    if (have_first) {
        copy(act_.first_lam.data(), solved_.lam.data(), n2_); copy(act_.first_u.data(), solved_.u.data(), n2_);
        copy8(act_.first_state.data(), solved_.state.data()); copy(act_.first_sign.data(), solved_.sign.data());
        return ContactStatus::ok;
    }
    int it2 = 0;
    const ContactStatus s = damped_newton(plate_z, ds, atol, it2);
    it += it2;
    if (s != ContactStatus::ok) return s;
    classify(solved_.lam.data(), solved_.u.data(), plate_z, ds, act_.F.data(), solved_.state.data(),
             solved_.sign.data());
    return ContactStatus::ok;
}

inline double ContactSolverKernel::classify(const double* lam, const double* u, double plate_z, double ds,
                                            double* F, std::int8_t* state, double* sgn) const noexcept {
    const std::size_t n = n_;
    const double r = r_;
    for (std::size_t i = 0; i < n; ++i) {
        const double lt = lam[i], ln = lam[n + i];
        const double g = plate_z - (z0_[i] + u[n + i]);
        const double w = (u[i] - uy_prev_[i]) - ds;
        const double an = ln - r * g;
        const bool act = an > 0;
        const double b = act_.mu[i] * (act ? an : 0.0);
        const double tau = lt - r * w;
        const bool stick = act && std::fabs(tau) <= b;
        const bool slip = act && !stick;
        const double s = tau > 0 ? 1.0 : (tau < 0 ? -1.0 : (tau == tau ? 0.0 : tau));
        F[i] = stick ? r * w : (slip ? lt - b * s : lt);
        F[n + i] = act ? r * g : ln;
        state[i] = stick ? kContactStick : (slip ? kContactSlip : kContactOpen);
        sgn[i] = slip ? s : 0.0;
    }
    return max_abs(F, n2_);
}

inline void ContactSolverKernel::jacobian(const std::int8_t* state, const double* sign, double* J) const noexcept {
    const std::size_t n = n_, n2 = n2_;
    const double r = r_;
    for (std::size_t i = 0; i < n2 * n2; ++i) J[i] = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
        double* jt = J + i * n2;
        double* jn = J + (n + i) * n2;
        const double* cy = C_.data() + i * n2;        // row i of C: dw/dlam = CP[i, :]
        const double* cz = C_.data() + (n + i) * n2;  // row n+i: dg/dlam = -CP[n+i, :]
        const bool act = state[i] != kContactOpen;
        if (state[i] == kContactStick) {
            for (std::size_t j = 0; j < n; ++j) { jt[j] = r * cy[j]; jt[n + j] = r * -cy[n + j]; }
        } else if (state[i] == kContactSlip) {
            // e_t - mu s (e_n - r dg) = e_t - mu s (e_n + r CP[n+i, :])
            const double ms = act_.mu[i] * sign[i];
            for (std::size_t j = 0; j < n; ++j) {
                jt[j] = -ms * (r * cz[j]);
                jt[n + j] = -ms * (r * -cz[n + j]);
            }
            jt[i] += 1.0;
            jt[n + i] = -ms * (1.0 + r * -cz[n + i]);
        } else {
            jt[i] = 1.0;
        }
        if (act) {
            for (std::size_t j = 0; j < n; ++j) { jn[j] = r * -cz[j]; jn[n + j] = r * cz[n + j]; }
        } else {
            jn[n + i] = 1.0;
        }
    }
}

// The damped semismooth Newton method on F from the committed forces, result in
// solved_.lam / solved_.u (the classification is redone by the caller).
inline ContactStatus ContactSolverKernel::damped_newton(double plate_z, double ds, double atol, int& it) noexcept {
    const std::size_t n2 = n2_;
    double* lam = solved_.lam.data();
    double* u = solved_.u.data();
    copy(lam_.data(), lam, n2);
    displacement(lam, u);
    double* F = act_.F.data();
    std::int8_t* st = act_.state.data();
    double* sg = act_.sign.data();
    double norm = classify(lam, u, plate_z, ds, F, st, sg);
    it = 0;
    while (norm > atol) {
        if (it >= params.max_iter) {
            err_.residual = norm; err_.atol = atol; err_.info = params.max_iter;
            return ContactStatus::no_convergence;
        }
        jacobian(st, sg, newton_.J.data());
        double merit = 0.0;
        for (std::size_t i = 0; i < n2; ++i) { newton_.step[i] = -F[i]; merit += F[i] * F[i]; }
        if (lu_factor(newton_.J.data(), n2, n2, newton_.piv.data()) != 0) {
            err_.info = it;
            return ContactStatus::singular_jacobian;
        }
        lu_solve(newton_.J.data(), n2, n2, newton_.piv.data(), newton_.step.data());
        double t = 1.0;
        double* F2 = newton_.F.data();
        std::int8_t* st2 = act_.next_state.data();
        double* sg2 = act_.next_sign.data();
        double norm2 = 0.0;
        while (true) {
            for (std::size_t i = 0; i < n2; ++i) newton_.lam[i] = lam[i] + t * newton_.step[i];
            displacement(newton_.lam.data(), newton_.u.data());
            norm2 = classify(newton_.lam.data(), newton_.u.data(), plate_z, ds, F2, st2, sg2);
            double m2 = 0.0;
            for (std::size_t i = 0; i < n2; ++i) m2 += F2[i] * F2[i];
            if (m2 <= (1 - 1e-4 * t) * merit || t < 1e-6) break;
            t *= 0.5;
        }
        copy(newton_.lam.data(), lam, n2);
        copy(newton_.u.data(), u, n2);
        copy(F2, F, n2);
        for (std::size_t i = 0; i < n_; ++i) { st[i] = st2[i]; sg[i] = sg2[i]; }
        norm = norm2;
        ++it;
    }
    return ContactStatus::ok;
}

}  // namespace tactile
