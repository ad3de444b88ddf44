// Frictional contact of one ridge with a rigid plate on the condensed surface
// compliance: the event-driven path following of tactile_mirror/contact/solver.py
// (ContactSolver.follow / step), with its breakaway cascade solved by the
// primal-dual active-set (semismooth Newton) iteration and its damped-Newton fallback.
//
// The algorithm, its tolerances, the classification and the reported state are
// those of the Python reference (ContactSolver(backend="python")); see its module
// docstring ("Event-driven path following") for the equations. Here:
//
// * sizes are fixed at construction (n contact nodes, 2n unknowns) and every
//   workspace is allocated there; `follow` and `step` allocate nothing, take no lock,
//   make no system call and throw nothing: they return a ContactStatus;
// * `follow` saves the history at its start and restores it on an error, so a failed
//   call leaves the solver as it was; a pad undoes the ridges that succeeded with
//   `restore`;
// * the friction law is the rate-independent one of the reference: a node that
//   breaks away drops to the kinetic cone at the breakaway point, and the load it
//   sheds is carried at that same load (the breakaway cascade, `cascade`);
// * the pieces are separate functions (classification, the piece system and its
//   factorisation, the triangular solve, the Newton residual and Jacobian).
//
// The dense LU is partial pivoting (row-major, blocked right-looking). A pivot that
// is exactly zero is a singular system, as LAPACK getrf reports it. Factors are
// reused while the piece (classification and slip coefficients) is unchanged; a piece
// that differs from the factored one in a few nodes (the slip front moved by a node)
// is solved by bordering the factored one (a Schur complement of at most 64 rows and
// columns, its entries kept from one piece to the next; a stuck node that slides costs two borders, its slip law as a row), and a
// piece that adds touching nodes (the contact growing under the press) extends the
// base's factors by them (extend_base, O(nb m^2)), so refactorisations are rare. The
// base solves of the unit right-hand sides (the responses to a unit plate motion) are
// kept with the base, so the unit responses of a bordered piece cost O(m nb) besides
// their compliance products; so is the last base solve of a load's right-hand side,
// which the active-set steps and breakaway-cascade rounds of one load point share
// (reused when base and right-hand side are bitwise the same: the same bits as a
// fresh solve; about a tenth of a gross slip's cost). No iterative refinement: the
// bordered solves agree with the reference's fresh LAPACK factorisations as closely as
// the reference's two stepping modes agree with each other (tests/test_contact_cpp.py).
// A piece's displacements come from its own equations where they fix them
// (piece_displacement: only the open nodes and the sliding nodes' u_y take dot products
// with C). Within one piece the response is affine in the plate position; the
// active-set iteration of the breakaway cascade and the per-sample stepping (every)
// serve a piece met a third time from its reference solution and unit responses in
// O(n) (piece_response): a sample of `every` that meets no event costs no solve with
// the factors and no product with C (on fig6 stepped per sample the median step went
// from 17 to 5 us, the mean from 28 to 17 us).
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include "contact_dense.hpp"

namespace tactile {

enum class ContactStatus : int {
    ok = 0,
    non_finite_position = 1,  // plate_y or plate_z is NaN, infinite or beyond kMaxPlatePosition
    singular_piece = 2,       // the active-set system has a zero pivot (info: its 1-based row)
    singular_jacobian = 3,    // the damped-Newton Jacobian has a zero pivot (info: Newton iteration)
    no_convergence = 4,       // max_iter damped-Newton iterations without reaching the tolerance
    status_cycle = 5,         // path following: the statuses at one load point cycle (info: sets met)
};

enum : std::int8_t { kContactOpen = 0, kContactStick = 1, kContactSlip = 2 };

// The largest plate coordinate a step takes, m (a 2 mm ridge): farther is no contact of
// this model, and a finite 1e308 overflowed the solve into NaN forces that then stayed
// in the history. Refused as a non-finite position is (solver.MAX_PLATE_POSITION).
constexpr double kMaxPlatePosition = 1.0;

// Solver parameters, read at every step (the caller may change them between steps).
struct ContactParams {
    double mu = 0.5;           // static Coulomb coefficient
    double mu_kinetic = 0.5;   // kinetic coefficient (0 < mu_kinetic <= mu)
    double tol = 1e-10;        // relative tolerance of the Alart-Curnier residual
    int max_iter = 60;         // damped-Newton iterations before no_convergence
    int max_active_set_iter = 25;
};

class ContactSolverKernel {
public:
    // compliance: (2n, 2n) row-major, symmetric (u = C f, f = (f_y, f_z));
    // node_z, weights: (n,); r: the Alart-Curnier stiffness, 1 / mean(diag C) (N/m
    // per m; given so both backends use the same rounding of it); w_tol: slip
    // increment below which a node on the cone counts as not moving (m).
    ContactSolverKernel(std::size_t n, const double* compliance, const double* node_z, const double* weights,
                        double r, double w_tol)
        : n_(n), n2_(2 * n), C_(compliance, compliance + 4 * n * n), z0_(node_z, node_z + n),
          w_(weights, weights + n), w_tol_(w_tol), r_(r) {
        z0_max_ = z0_[0];
        argmax_z0_ = 0;
        for (std::size_t i = 1; i < n; ++i)
            if (z0_[i] > z0_max_) { z0_max_ = z0_[i]; argmax_z0_ = i; }
        auto vec = [](std::size_t k) { return std::vector<double>(k, 0.0); };
        lam_ = vec(n2_); uy_prev_ = vec(n); sign_ = vec(n);
        state_.assign(n, kContactOpen); sliding_.assign(n, 0);
        c_lam_ = vec(n2_); c_u_ = vec(n2_); c_sign_ = vec(n); c_forces_ = vec(n2_);
        c_state_.assign(n, kContactOpen); c_reported_.assign(n, kContactOpen);
        mu_node_ = vec(n); F_ = vec(n2_); F2_ = vec(n2_); u2_ = vec(n2_); lam2_ = vec(n2_); d_ = vec(n2_);
        ws_state_.assign(n, kContactOpen); ws_sign_ = vec(n); ws_state2_.assign(n, kContactOpen); ws_sign2_ = vec(n);
        rhs_ = vec(n2_); M_ = vec(n2_ * n2_); piv_.assign(n2_, 0); J_ = vec(n2_ * n2_); jpiv_.assign(n2_, 0);
        bnode_.assign(n2_, 0); bkind_.assign(n2_, 0);
        pos_ln_.assign(n, -1); pos_lt_.assign(n, -1);
        base_state_.assign(n, kContactOpen); base_coef_ = vec(n);
        vcol_.assign(kMaxBorder, nullptr); vslot_.assign(kMaxBorder, 0); slot_used_.assign(kColCache, 0); Wt_ = vec(kMaxBorder * n2_); S_ = vec(kMaxBorder * kMaxBorder);
        vnew_ = vec(kMaxBorder * n2_); new_col_.assign(kMaxBorder, 0);
        spiv_.assign(kMaxBorder, 0); by_ = vec(kMaxBorder); brow_.resize(kMaxBorder); bcol_.resize(kMaxBorder);
        vcache_ = vec(kColCache * n2_); ccol_.resize(kColCache);
        obrow_.resize(kMaxBorder); obcol_.resize(kMaxBorder); orcoef_ = vec(kMaxBorder); occoef_ = vec(kMaxBorder);
        Wt2_ = vec(kMaxBorder * n2_); S0_ = vec(kMaxBorder * kMaxBorder); S1_ = vec(kMaxBorder * kMaxBorder);
        rmap_.assign(kMaxBorder, -1); cmap_.assign(kMaxBorder, -1);
        node_head_.assign(n, -1); chain_next_.assign(kMaxBorder, -1);
        cache_next_.assign(kColCache, -1); trow_.resize(kMaxBorder); tcol_.resize(kMaxBorder);
        rhs_in_ = vec(n2_); rhs_out_ = vec(n2_);
        aff_lam_ = vec(n2_); aff_u_ = vec(n2_); aff_lz_ = vec(n2_); aff_uz_ = vec(n2_); aff_ly_ = vec(n2_);
        aff_uy_ = vec(n2_); aff_v_ = vec(n);
        key_state_.assign(n, kContactOpen); key_coef_ = vec(n);
        slip_coef_ = vec(n);
        plam_ = vec(n2_); free_rows_.assign(n2_, 0);
        pu_ = vec(n2_); pl1_ = vec(n2_); pu1_ = vec(n2_); rs_ = vec(n2_); rz_ = vec(n2_); us_ = vec(n2_);
        uz_ = vec(n2_); ukey_sign_ = vec(n); ev_frac_ = vec(4 * n); prev_sign_ = vec(n);
        sv_lam_ = vec(n2_); sv_u_ = vec(n2_); sv_sign_ = vec(n); o_lam_ = vec(n2_); o_u_ = vec(n2_); zunit_ = vec(2 * n2_);
        fl_lam_ = vec(n2_); fl_u_ = vec(n2_); fl_sign_ = vec(n); fl_state_.assign(n, kContactOpen);
        ukey_state_.assign(n, kContactOpen); ev_kind_.assign(4 * n, 0); prev_state_.assign(n, kContactOpen);
        sv_state_.assign(n, kContactOpen); ev_node_.assign(4 * n, 0);
        seen_.assign(kSeenCap * n, 0); key_.assign(n, 0); seen_resolved_.assign(kSeenCap, false);
        // event tolerances of the reference for w_tol = 1e-11 H: gaps 1e-14 H (m),
        // forces 1e-12 r H (N/m); set_event_tolerances sets them exactly
        g_tol_ = 1e-3 * w_tol;
        f_tol_ = 0.1 * r * w_tol;
        evt_g_tol_ = 1e-5 * w_tol;
        evt_f_tol_ = 1e-4 * r * w_tol;
        reset();
    }

    std::size_t n_nodes() const noexcept { return n_; }
    double r() const noexcept { return r_; }
    ContactParams params;

    // True from construction or reset() until the history first changes (a follow or
    // step of at least one sample, set_history, set_path_history).
    bool pristine() const noexcept { return pristine_; }
    // The same model (compliance, node heights, weights, r, w_tol), parameters and
    // event tolerances. The kernel is deterministic: two kernels of the same
    // configuration and history given the same plate path compute the same bits
    // (a pad's mirror-image ridges under a symmetric finger; see bind_contact.cpp).
    bool same_config(const ContactSolverKernel& o) const noexcept {
        if (n_ != o.n_ || r_ != o.r_ || w_tol_ != o.w_tol_) return false;
        const ContactParams &a = params, &b = o.params;
        if (a.mu != b.mu || a.mu_kinetic != b.mu_kinetic || a.tol != b.tol || a.max_iter != b.max_iter ||
            a.max_active_set_iter != b.max_active_set_iter)
            return false;
        if (g_tol_ != o.g_tol_ || f_tol_ != o.f_tol_ || evt_g_tol_ != o.evt_g_tol_ || evt_f_tol_ != o.evt_f_tol_)
            return false;
        return std::memcmp(z0_.data(), o.z0_.data(), n_ * sizeof(double)) == 0 &&
               std::memcmp(w_.data(), o.w_.data(), n_ * sizeof(double)) == 0 &&
               std::memcmp(C_.data(), o.C_.data(), C_.size() * sizeof(double)) == 0;
    }

    // Gaps (m) and forces (N/m) this close to zero count as zero in the event search.
    // evt_g_tol / evt_f_tol: the "decreasing" thresholds of the event search (gaps,
    // forces); g_tol / f_tol: the cascade's and the cycle rule's zero tests.
    void set_event_tolerances(double g_tol, double f_tol, double evt_g_tol, double evt_f_tol) noexcept {
        g_tol_ = g_tol; f_tol_ = f_tol; evt_g_tol_ = evt_g_tol; evt_f_tol_ = evt_f_tol;
    }

    // Back to the undeformed, unloaded state.
    void reset() noexcept {
        fill(pu_, 0.0);
        z_prev_ = 0.0; has_z_ = false; unit_valid_ = false;
        solves_ = 0; events_ = 0;
        fill(lam_, 0.0); fill(uy_prev_, 0.0); fill(sign_, 0.0);
        fill8(state_, kContactOpen); fill8(sliding_, 0);
        s_prev_ = 0.0;
        lu_valid_ = false;
        aff_stage_ = 0;
        has_candidate_ = false;
        pristine_ = true;
        fr_mu_ = params.mu; fr_muk_ = params.mu_kinetic;
    }

    // One step of the path following to the plate position (plate_y, plate_z), the
    // load moving linearly from the last one, every event resolved at its point (the
    // reference's ContactSolver.step, every = true; every = false takes the end of the
    // step from the piece's unit responses, O(n) while no status changes); the
    // results are read with forces(), displacement(), reported_state(),
    // slip_fraction() and iterations() (the solves it took). On an error the history
    // is unchanged.
    ContactStatus step(double plate_y, double plate_z, bool every = true) noexcept {
        const long s0 = solves_;
        const ContactStatus s = follow(&plate_y, &plate_z, 1, every, o_lam_.data(), o_u_.data(), c_reported_.data(),
                                       0, 0);
        if (s != ContactStatus::ok) return s;
        report(o_lam_.data(), c_reported_.data(), c_forces_.data(), c_frac_);
        c_iterations_ = static_cast<int>(solves_ - s0);
        return s;
    }

    // forces f = (lt, -ln) (unless forces is null) and the slip fraction (weight of SLIP
    // nodes over the weight of touching nodes) of the forces lam and statuses st of one sample
    void report(const double* lam, const std::int8_t* st, double* forces, double& frac) const noexcept {
        const std::size_t n = n_;
        double total = 0.0, slipping = 0.0;
        for (std::size_t i = 0; i < n; ++i) {
            if (forces) {
                forces[i] = lam[i];
                forces[n + i] = -lam[n + i];
            }
            if (st[i] != kContactOpen) total += w_[i];
            if (st[i] == kContactSlip) slipping += w_[i];
        }
        frac = total > 0 ? slipping / total : 0.0;
    }

    // Solve the step to (plate_y, plate_z) with the cones mu_node_, from the
    // classification (st, sg) (which must be ws_state_ / ws_sign_: they are used as
    // workspace): active-set iterations, then the damped Newton method if they cycle.
    // The result is in c_lam_, c_u_, c_state_, c_sign_; `it` counts the iterations.
    // exact: go on while the classification still changes, even once the residual is
    // within atol (the exact solution of its piece); if the pieces cycle, the first
    // answer within the tolerance.
    ContactStatus solve_load(std::int8_t* st, double* sg, double plate_z, double plate_y, double ds, double atol,
                             int& it, bool exact = false) noexcept {
        const std::size_t n = n_;
        it = 0;
        std::int8_t* nst = ws_state2_.data();
        double* nsg = ws_sign2_.data();
        bool have_first = false;
        for (int k = 1; k <= params.max_active_set_iter; ++k) {
            it = k;
            const int info = piece_response(st, sg, plate_z, plate_y, ds, c_lam_.data(), c_u_.data());
            if (info != 0) { err_info_ = info; return ContactStatus::singular_piece; }
            const double fmax = classify(c_lam_.data(), c_u_.data(), plate_z, ds, F_.data(), nst, nsg);
            bool same = true;
            for (std::size_t i = 0; i < n && same; ++i)
                same = nst[i] == st[i] && (st[i] != kContactSlip || nsg[i] == sg[i]);
            if (fmax <= atol) {
                if (!exact || same) {
                    copy8(nst, c_state_.data()); copy(nsg, c_sign_.data());
                    return ContactStatus::ok;
                }
                if (!have_first) {
                    copy(c_lam_.data(), fl_lam_.data(), n2_); copy(c_u_.data(), fl_u_.data(), n2_);
                    copy8(nst, fl_state_.data()); copy(nsg, fl_sign_.data());
                    have_first = true;
                }
            } else if (same) {
                break;  // same piece but not converged: round-off trouble, use Newton
            }
            std::int8_t* ts = st; st = nst; nst = ts;
            double* tg = sg; sg = nsg; nsg = tg;
        }
        if (have_first) {
            copy(fl_lam_.data(), c_lam_.data(), n2_); copy(fl_u_.data(), c_u_.data(), n2_);
            copy8(fl_state_.data(), c_state_.data()); copy(fl_sign_.data(), c_sign_.data());
            return ContactStatus::ok;
        }
        int it2 = 0;
        const ContactStatus s = damped_newton(plate_z, ds, atol, it2);
        it += it2;
        if (s != ContactStatus::ok) return s;
        classify(c_lam_.data(), c_u_.data(), plate_z, ds, F_.data(), c_state_.data(), c_sign_.data());
        return ContactStatus::ok;
    }

    // ---- results of the last solve (valid after it returned ok; kept by commit)
    const double* forces() const noexcept { return c_forces_.data(); }        // (2n) f = (lt, -ln), N/m
    const double* displacement() const noexcept { return o_u_.data(); }       // (2n) (u_y, u_z), m
    const std::int8_t* reported_state() const noexcept { return c_reported_.data(); }  // (n)
    double slip_fraction() const noexcept { return c_frac_; }
    int iterations() const noexcept { return c_iterations_; }
    // Piece factorisations since construction (a step that reuses the factors adds none).
    long factorizations() const noexcept { return n_factorizations_; }
    // Pieces solved by bordering the factored base piece instead of refactoring.
    long updates() const noexcept { return n_updates_; }
    // Times the base was extended by the nodes a piece added (extend_base) instead of
    // refactored.
    long extensions() const noexcept { return n_extensions_; }
    // Bordered updates that kept every border row and column of the last one and added to
    // it (the border's W^T rows and Schur complement extended in place, extend_s).
    long border_extensions() const noexcept { return n_border_ext_; }
    // Piece solves served by the affine response of an unchanged piece (O(n) each).
    long affine_steps() const noexcept { return n_affine_; }
    // Base solves of a load's right-hand side served by the last one (same base, same
    // right-hand side: the iterations of one point).
    long rhs_reuses() const noexcept { return n_rhs_reused_; }
    // ---- error details of the last failed solve
    long error_info() const noexcept { return err_info_; }
    double error_residual() const noexcept { return err_residual_; }
    double error_tolerance() const noexcept { return err_atol_; }

    // ---- committed contact history (read / restore)
    const double* lam() const noexcept { return lam_.data(); }
    const double* uy_prev() const noexcept { return uy_prev_.data(); }
    const double* sign() const noexcept { return sign_.data(); }
    const std::int8_t* state() const noexcept { return state_.data(); }
    const std::uint8_t* sliding() const noexcept { return sliding_.data(); }
    double s_prev() const noexcept { return s_prev_; }
    void set_history(const double* lam, const double* uy_prev, const double* sign, const std::int8_t* state,
                     const std::uint8_t* sliding, double s_prev) noexcept {
        copy(lam, lam_.data(), n2_); copy(uy_prev, uy_prev_.data()); copy(sign, sign_.data());
        copy8(state, state_.data());
        for (std::size_t i = 0; i < n_; ++i) sliding_[i] = sliding[i] ? 1 : 0;
        s_prev_ = s_prev;
        aff_stage_ = 0;
        has_candidate_ = false;
        pristine_ = false;
        fr_mu_ = params.mu; fr_muk_ = params.mu_kinetic;  // a given history holds under the current friction
    }

    // ---- event-driven path following (the Python reference's ContactSolver.follow)
    //
    // Between two samples the plate moves linearly, L(theta) = L0 + theta (L1 - L0),
    // L = (plate_y, plate_z). Every node has a status (OPEN; STICK, anchored; SLIP with
    // a sign, on the kinetic cone); for fixed statuses the forces are linear in the load
    // (a piece), so the path is followed from event to event: a gap closing, a pressure
    // reaching zero, a stuck node's traction reaching the static cone (breakaway, with
    // the breakaway cascade solved at that load), a sliding node's slip rate stopping.
    // every = true follows each sample interval as its own segment and solves the piece
    // at every sample (the reference; a piece met before with the same stick offsets is
    // solved by its affine response, piece_response); every = false takes the longest
    // run of samples with equal load increments as one segment and fills the samples from the piece's
    // responses to unit loads, so only events cost a solve and a load that does not
    // move costs nothing. The steps, tests and tolerances are those of the reference
    // (tactile_mirror/contact/solver.py, "Event-driven path following"), in the same
    // order.
    //
    // Outputs (each may be null): row k of lam_out / u_out (2n doubles at
    // lam_out + k * out_stride2) and of state_out (n int8 at state_out + k *
    // out_stride1) get the forces (lt, ln), displacements and statuses of sample k. On
    // an error the path history is what it was before the call (and the outputs of
    // the samples before the failing one are written).
    ContactStatus follow(const double* ys, const double* zs, std::size_t N, bool every, double* lam_out,
                         double* u_out, std::int8_t* state_out, std::size_t out_stride2,
                         std::size_t out_stride1) noexcept {
        err_info_ = 0; err_residual_ = 0.0; err_atol_ = 0.0;
        for (std::size_t k = 0; k < N; ++k) {
            // (NaN fails the comparison too)
            if (!(std::fabs(ys[k]) <= kMaxPlatePosition && std::fabs(zs[k]) <= kMaxPlatePosition)) {
                err_info_ = static_cast<long>(k);
                return ContactStatus::non_finite_position;
            }
        }
        save();
        if (N) pristine_ = false;
        out_lam_ = lam_out; out_u_ = u_out; out_state_ = state_out;
        out_s2_ = out_stride2; out_s1_ = out_stride1;
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
            out_row0_ = k;
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

    // Outputs of follow besides the full rows, per sample (each may be null): q linear
    // functionals P lam of the forces (row k at proj + k * stride_q; P set by
    // set_projection), the slip fraction (frac + k * stride_f) and flags (flags + k *
    // stride_f: bit 0 some node touches, bit 1 gross slip: touching and none stuck). Along
    // a piece they cost O(q) a sample (P lam is affine along it), not O(n).
    struct Extra {
        double* proj = nullptr;
        std::size_t stride_q = 0;
        double* frac = nullptr;
        std::int8_t* flags = nullptr;
        std::size_t stride_f = 0;
    };
    // P: (q, 2n) row-major, applied to lam = (lt, ln). Allocates: call it before stepping.
    void set_projection(const double* P, std::size_t q) {
        q_ = q;
        Pt_.assign(q * n2_, 0.0);  // column-major: the q entries of column j together
        for (std::size_t a = 0; a < q; ++a)
            for (std::size_t j = 0; j < n2_; ++j) Pt_[j * q + a] = P[a * n2_ + j];
        pc_.assign(q, 0.0);
        pd_.assign(q, 0.0);
    }
    std::size_t projection_size() const noexcept { return q_; }
    ContactStatus follow(const double* ys, const double* zs, std::size_t N, bool every, double* lam_out,
                         double* u_out, std::int8_t* state_out, std::size_t out_stride2, std::size_t out_stride1,
                         const Extra& extra) noexcept {
        ex_ = extra;
        if (!q_) ex_.proj = nullptr;
        const ContactStatus s = follow(ys, zs, N, every, lam_out, u_out, state_out, out_stride2, out_stride1);
        ex_ = Extra{};
        return s;
    }

    // Solves and events of the path following since the last reset.
    long solves() const noexcept { return solves_; }
    long events() const noexcept { return events_; }
    // Plate height of the current state (valid when placed()).
    double z_prev() const noexcept { return z_prev_; }
    bool placed() const noexcept { return has_z_; }
    const double* path_displacement() const noexcept { return pu_.data(); }
    // Load point of the last failure of follow (for the error message).
    double error_y() const noexcept { return err_y_; }
    double error_z() const noexcept { return err_z_; }

    // The history in one slot (save) and back (restore): follow saves at its start, so
    // a caller stepping several ridges can undo the ones that succeeded.
    void save() noexcept {
        copy(lam_.data(), sv_lam_.data(), n2_); copy(pu_.data(), sv_u_.data(), n2_);
        copy8(state_.data(), sv_state_.data()); copy(sign_.data(), sv_sign_.data());
        sv_s_ = s_prev_; sv_z_ = z_prev_; sv_has_z_ = has_z_; sv_solves_ = solves_; sv_events_ = events_;
        sv_pristine_ = pristine_;
        sv_fr_mu_ = fr_mu_; sv_fr_muk_ = fr_muk_;
    }
    void restore() noexcept {
        copy(sv_lam_.data(), lam_.data(), n2_); copy(sv_u_.data(), pu_.data(), n2_);
        copy(pu_.data(), uy_prev_.data());
        copy8(sv_state_.data(), state_.data()); copy(sv_sign_.data(), sign_.data());
        for (std::size_t i = 0; i < n_; ++i) sliding_[i] = state_[i] == kContactSlip;
        s_prev_ = sv_s_; z_prev_ = sv_z_; has_z_ = sv_has_z_; solves_ = sv_solves_; events_ = sv_events_;
        pristine_ = sv_pristine_;
        fr_mu_ = sv_fr_mu_; fr_muk_ = sv_fr_muk_;
        unit_valid_ = false;
        // the affine response of the current piece (piece_response) stays: it holds while
        // the piece and its stuck nodes' offsets do, and both are checked where it is
        // used; the restored history is then served as the uninterrupted one would be
    }

    // History as the path follower keeps it: lam, the statuses and signs, s_prev and
    // the plate height (has_z false: not placed; then it is derived from the
    // touching nodes as the reference does). The displacements are C P lam.
    void set_path_history(const double* lam, const double* sign, const std::int8_t* state, double s_prev,
                          bool has_z, double z_prev) noexcept {
        const std::size_t n = n_;
        copy(lam, lam_.data(), n2_); copy(sign, sign_.data()); copy8(state, state_.data());
        displacement(lam_.data(), pu_.data());
        copy(pu_.data(), uy_prev_.data());
        for (std::size_t i = 0; i < n; ++i) sliding_[i] = state_[i] == kContactSlip;
        s_prev_ = s_prev;
        bool any = false;
        for (std::size_t i = 0; i < n; ++i) any |= state_[i] != kContactOpen;
        if (has_z) {
            z_prev_ = z_prev; has_z_ = true;
        } else if (any) {  // the plate face is where the touching nodes are
            std::size_t k = 0;
            for (std::size_t i = 1; i < n; ++i) if (lam_[n + i] > lam_[n + k]) k = i;
            z_prev_ = z0_[k] + pu_[n + k]; has_z_ = true;
        } else {
            z_prev_ = 0.0; has_z_ = false;
        }
        unit_valid_ = false;
        aff_stage_ = 0;
        has_candidate_ = false;
        pristine_ = false;
        fr_mu_ = params.mu; fr_muk_ = params.mu_kinetic;
    }

private:
    std::size_t segment_end(const double* ys, const double* zs, std::size_t N, std::size_t k) const noexcept {
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
    void fill_rows(std::size_t a, std::size_t b, const double* lc, const double* uc, const double* l1, const double* u1,
              double th, std::size_t L) noexcept {
        const std::size_t n2 = n2_;
        if (a >= b) return;
        double frac = 0.0;
        std::int8_t flags = 0;
        if (ex_.proj) {  // P lc and P (l1 - lc), once for the rows
            const std::size_t q = q_;
            double* pc = pc_.data();
            double* pd = pd_.data();
            for (std::size_t c = 0; c < q; ++c) pc[c] = pd[c] = 0.0;
            for (std::size_t j = 0; j < n2; ++j) {
                const double* col = Pt_.data() + j * q;
                const double x = lc[j], d = l1 ? l1[j] - lc[j] : 0.0;
                if (x != 0.0) for (std::size_t c = 0; c < q; ++c) pc[c] += col[c] * x;
                if (d != 0.0) for (std::size_t c = 0; c < q; ++c) pd[c] += col[c] * d;
            }
        }
        if (ex_.frac || ex_.flags) {
            report(lc, state_.data(), nullptr, frac);
            bool touch = false, stick = false;
            for (std::size_t i = 0; i < n_; ++i) {
                touch |= state_[i] != kContactOpen;
                stick |= state_[i] == kContactStick;
            }
            flags = static_cast<std::int8_t>((touch ? 1 : 0) | (touch && !stick ? 2 : 0));
        }
        for (std::size_t k = a; k < b; ++k) {
            const std::size_t row = out_row0_ + k;
            double f = 0.0;
            if (l1) f = (static_cast<double>(k + 1) / static_cast<double>(L) - th) / (1.0 - th);
            if (ex_.proj) {
                double* o = ex_.proj + row * ex_.stride_q;
                for (std::size_t c = 0; c < q_; ++c) o[c] = pc_[c] + f * pd_[c];
            }
            if (ex_.frac) ex_.frac[row * ex_.stride_f] = frac;
            if (ex_.flags) ex_.flags[row * ex_.stride_f] = flags;
            if (out_lam_) {
                double* o = out_lam_ + row * out_s2_;
                if (l1) for (std::size_t i = 0; i < n2; ++i) o[i] = lc[i] + f * (l1[i] - lc[i]);
                else copy(lc, o, n2);
            }
            if (out_u_) {
                double* o = out_u_ + row * out_s2_;
                if (l1) for (std::size_t i = 0; i < n2; ++i) o[i] = uc[i] + f * (u1[i] - uc[i]);
                else copy(uc, o, n2);
            }
            if (out_state_) copy8(state_.data(), out_state_ + row * out_s1_);
        }
    }

    void set_path_cones() noexcept {
        for (std::size_t i = 0; i < n_; ++i) mu_node_[i] = state_[i] == kContactSlip ? params.mu_kinetic : params.mu;
    }

    // Responses (rs, us) to a unit plate displacement along y and (rz, uz) to a unit
    // rise of the plate for the current statuses, kept while they and mu do not change.
    int unit_response() noexcept {
        const std::size_t n = n_;
        if (unit_valid_ && ukey_mu_ == params.mu && ukey_muk_ == params.mu_kinetic) {
            bool same = true;
            for (std::size_t i = 0; i < n && same; ++i) same = ukey_state_[i] == state_[i] && ukey_sign_[i] == sign_[i];
            if (same) return 0;
        }
        unit_valid_ = false;
        set_path_cones();
        const int info = factor_piece(state_.data(), sign_.data());
        if (info != 0) return info;
        solve_prepared(0.0, 0.0, rs_.data(), true, 0.0, 1.0);
        solve_prepared(0.0, 0.0, rz_.data(), true, 1.0, 0.0);
        piece_displacement(rs_.data(), us_.data(), true, 0.0, 1.0, 0.0, 0.0);
        piece_displacement(rz_.data(), uz_.data(), true, 1.0, 0.0, 0.0, 0.0);
        copy8(state_.data(), ukey_state_.data()); copy(sign_.data(), ukey_sign_.data());
        ukey_mu_ = params.mu; ukey_muk_ = params.mu_kinetic;
        unit_valid_ = true;
        ++solves_;
        return 0;
    }

    // The status sets met at the current point (a cycle guard, the reference's
    // `seen`): one byte per node (3 state + sign + 1), plain or "resolved" entries.
    void encode_statuses(std::int8_t* key) const noexcept {
        for (std::size_t i = 0; i < n_; ++i)
            key[i] = static_cast<std::int8_t>(3 * state_[i] + (sign_[i] > 0 ? 2 : (sign_[i] < 0 ? 0 : 1)));
    }
    bool seen_has(const std::int8_t* key, bool resolved) const noexcept {
        for (std::size_t q = 0; q < n_seen_; ++q) {
            if (seen_resolved_[q] != resolved) continue;
            if (std::memcmp(seen_.data() + q * n_, key, n_) == 0) return true;
        }
        return false;
    }
    bool seen_add(const std::int8_t* key, bool resolved) noexcept {
        if (n_seen_ >= kSeenCap) return false;
        std::memcpy(seen_.data() + n_seen_ * n_, key, n_);
        seen_resolved_[n_seen_++] = resolved;
        return true;
    }

    // A status change at the current point (the reference's _changed): counted; if
    // the statuses return to a set already met at this point, all of them are decided
    // together by resolve_point; a second return is a cycle (status_cycle).
    ContactStatus changed(double tiny_y, double tiny_z) noexcept {
        ++events_;
        std::int8_t* key = key_.data();
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

    ContactStatus cycle_error() noexcept {
        err_info_ = static_cast<long>(n_seen_);
        err_y_ = s_prev_; err_z_ = z_prev_;
        return ContactStatus::status_cycle;
    }

    // The start of a solve at the current point with the plate face at zp: statuses and
    // signs back to the accepted ones, the path's cones, the length scale of the
    // tolerance, and the working classification copied from the accepted one. Returns
    // the absolute tolerance of the Alart-Curnier residual.
    double begin_point_solve(double zp) noexcept {
        copy8(state_.data(), prev_state_.data());
        copy(sign_.data(), prev_sign_.data());
        set_path_cones();
        set_scale_len(zp);
        copy8(state_.data(), ws_state_.data());
        copy(sign_.data(), ws_sign_.data());
        return params.tol * (r_ * scale_len_);
    }

    // The length scale of a solve with the plate face at zp: the indent, or the largest
    // tangential displacement (at least 1e-9 m).
    void set_scale_len(double zp) noexcept {
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
    ContactStatus resolve_point(double tiny_y, double tiny_z) noexcept {
        const std::size_t n = n_;
        const double sc = s_prev_, zc = z_prev_;
        const double ds = tiny_y, zp = zc + tiny_z;
        const double atol = begin_point_solve(zp);
        std::int8_t* st = ws_state_.data();
        double* sg = ws_sign_.data();
        int it = 0;
        const ContactStatus s = solve_load(st, sg, zp, sc + ds, ds, atol, it, true);
        if (s != ContactStatus::ok) { err_y_ = sc + ds; err_z_ = zp; return s; }
        ++solves_;
        const double* u = c_u_.data();
        for (std::size_t i = 0; i < n; ++i) {
            const std::int8_t cs = c_state_[i], p = prev_state_[i];
            const double gap = zp - (z0_[i] + u[n + i]);
            const bool grazing = cs == kContactOpen && p != kContactOpen && gap <= g_tol_;
            const std::int8_t ns = grazing ? p : cs;
            state_[i] = ns;
            sign_[i] = ns == kContactSlip ? (cs == kContactSlip ? c_sign_[i] : prev_sign_[i]) : 0.0;
            sliding_[i] = ns == kContactSlip;
        }
        return ContactStatus::ok;
    }

    // direct: the end of each piece by a solve of the piece for it; affine (every): that
    // solve served by piece_response, O(n) once the piece is met a third time with the
    // same stick offsets (see follow).
    ContactStatus follow_segment(double s1, double z1, std::size_t L, double eps, bool direct,
                                 bool affine) noexcept {
        const std::size_t n = n_, n2 = n2_;
        const double s0 = s_prev_, z0p = z_prev_;
        double th = 0.0;
        std::size_t j = 0;
        const std::size_t ns = L;
        n_seen_ = 0;  // status sets met at the current point
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
        double* l1 = pl1_.data();
        double* u1 = pu1_.data();
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
                if (info != 0) { err_info_ = info; return ContactStatus::singular_piece; }
                ++solves_;
            } else {
                const int info = unit_response();
                if (info != 0) { err_info_ = info; return ContactStatus::singular_piece; }
                const double ds = s1 - sc, dz = z1 - zc;
                for (std::size_t i = 0; i < n2; ++i) {
                    l1[i] = lc[i] + ds * rs_[i] + dz * rz_[i];
                    u1[i] = uc[i] + ds * us_[i] + dz * uz_[i];
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
            if (te > th) n_seen_ = 0;
            th = te;
            std::size_t count = 0;
            ContactStatus s = apply_events(n_ev, count);
            if (s != ContactStatus::ok) return s;
            s = changed(tiny_y, tiny_z);
            if (s != ContactStatus::ok) return s;
        }
    }

    // First point frac in [0, 1 + eps] of the piece (lc, uc) -> (l1, u1) where a node's
    // status must change; the events there go to ev_node_ / ev_kind_ (kind 0 contact, 1
    // separation, 2 / 3 breakaway with the friction force along +y / -y), kind-major as
    // the reference orders them. n_ev = 0: none.
    double first_event(const double* lc, const double* uc, const double* l1, const double* u1, double zc, double z1,
                       double eps, std::size_t& n_ev) noexcept {
        const std::size_t n = n_;
        const double mu = params.mu, tg = evt_g_tol_, tf = evt_f_tol_;
        // one pass over the nodes (each node's status decides which of its functions
        // count), the crossings of kind k at ev_frac_[k n + i], INFINITY where none
        auto cross = [](double pc, double p1, double tol) {
            const double drop = pc - p1;
            return drop > tol && p1 < 0 ? (pc > 0.0 ? pc : 0.0) / drop : INFINITY;
        };
        double* f0 = ev_frac_.data();
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
            if (ev_frac_[q] <= first + eps) {
                ev_kind_[n_ev] = static_cast<std::int8_t>(q / n);
                ev_node_[n_ev] = q % n;
                ++n_ev;
            }
        }
        return first;
    }

    ContactStatus apply_events(std::size_t n_ev, std::size_t& changes) noexcept {
        const std::size_t n = n_;
        double broke_ln = -INFINITY;
        bool any_broke = false;
        for (std::size_t e = 0; e < n_ev; ++e) {
            const std::size_t i = ev_node_[e];
            const int kind = ev_kind_[e];
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
            if (ev_kind_[e] >= 2) {
                any_broke = true;
                const double ln = lam_[n + ev_node_[e]];
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
    ContactStatus settle_friction() noexcept {
        if (fr_mu_ == params.mu && fr_muk_ == params.mu_kinetic) return ContactStatus::ok;
        bool touching = false;
        for (std::size_t i = 0; i < n_ && !touching; ++i) touching = state_[i] != kContactOpen;
        if (touching && has_z_) {
            std::size_t changes = 0;
            const ContactStatus s = cascade(changes);
            if (s != ContactStatus::ok) return s;
            if (changes) ++events_;
            unit_valid_ = false;
            aff_stage_ = 0;
            has_candidate_ = false;
        }
        fr_mu_ = params.mu; fr_muk_ = params.mu_kinetic;
        return ContactStatus::ok;
    }

    // The breakaway cascade at the current load (the reference's _cascade).
    ContactStatus cascade(std::size_t& changes) noexcept {
        const std::size_t n = n_;
        const double mu_k = params.mu_kinetic;
        const double zp = z_prev_, sp = s_prev_;
        const double atol = begin_point_solve(zp);
        std::int8_t* st = ws_state_.data();
        double* sg = ws_sign_.data();
        for (std::size_t round = 0; round <= n; ++round) {
            int it = 0;
            const ContactStatus s = solve_load(st, sg, zp, sp, 0.0, atol, it, true);
            if (s != ContactStatus::ok) { err_y_ = sp; err_z_ = zp; return s; }
            ++solves_;
            bool broke = false;
            for (std::size_t i = 0; i < n; ++i) {
                const bool moving = std::fabs(c_u_[i] - uy_prev_[i]) > w_tol_;
                if (c_state_[i] == kContactSlip && moving && mu_node_[i] > mu_k) { mu_node_[i] = mu_k; broke = true; }
            }
            if (!broke) break;
            st = ws_state_.data(); sg = ws_sign_.data();
            copy8(c_state_.data(), st); copy(c_sign_.data(), sg);
        }
        const double* lam = c_lam_.data();
        const double* u = c_u_.data();
        changes = 0;
        for (std::size_t i = 0; i < n; ++i) {
            const bool moving = std::fabs(u[i] - uy_prev_[i]) > w_tol_;
            const bool on_kinetic = std::fabs(lam[i]) >= mu_k * lam[n + i] - f_tol_;
            const std::int8_t s = c_state_[i], p = prev_state_[i];
            const bool slide_moved = s == kContactSlip && moving;
            const bool slide_kept = p == kContactSlip && s != kContactOpen && !moving && on_kinetic;
            const double gap = zp - (z0_[i] + u[n + i]);
            const bool grazing = s == kContactOpen && p != kContactOpen && gap <= g_tol_;
            std::int8_t ns = s == kContactOpen ? static_cast<std::int8_t>(kContactOpen)
                                               : (slide_moved || slide_kept ? static_cast<std::int8_t>(kContactSlip)
                                                                            : static_cast<std::int8_t>(kContactStick));
            double nsg = slide_moved ? c_sign_[i] : (slide_kept ? prev_sign_[i] : 0.0);
            if (grazing) { ns = p; nsg = prev_sign_[i]; }
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

public:

    // ---- the pieces (public for path-following steppers)

    // u = C P lam, P = diag(1, -1): C is symmetric, so column j of C P is row j of C
    // (sign-flipped for the normal block); only the nonzero forces contribute.
    void displacement(const double* lam, double* u) const noexcept { compliance_product(C_.data(), n_, lam, u); }

    // u = C P lam for forces lam solved for the prepared piece (solve_prepared with the
    // same plate_z, ds or unit loads az, ay): the piece's own equations give u on their
    // rows (u_z = plate_z - z0 on a touching node, g = 0; u_y = uy_prev + ds on a stuck
    // one, w = 0), so only the other rows (the open nodes, the sliding nodes' u_y) are
    // computed, as dot products of rows of the symmetric C with P lam. With most nodes
    // stuck that is a small part of the product (none at all when every node sticks);
    // the equation rows differ from the product by the solve's round-off only.
    void piece_displacement(const double* lam, double* u, bool unit, double az, double ay, double plate_z,
                            double ds) noexcept {
        const std::size_t n = n_, n2 = n2_;
        double* pl = plam_.data();
        for (std::size_t i = 0; i < n; ++i) { pl[i] = lam[i]; pl[n + i] = -lam[n + i]; }
        std::size_t* fr = free_rows_.data();
        std::size_t nf = 0;
        for (std::size_t i = 0; i < n; ++i) {
            const std::int8_t s = key_state_[i];
            if (s == kContactStick) u[i] = unit ? ay : uy_prev_[i] + ds;
            else fr[nf++] = i;
        }
        for (std::size_t i = 0; i < n; ++i) {
            if (key_state_[i] != kContactOpen) u[n + i] = unit ? az : plate_z - z0_[i];
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

    // Alart-Curnier residual F (2n) at (lam, u), the classification open / stick /
    // slip and the slip signs; returns max |F|. Uses the per-node cone of this step.
    double classify(const double* lam, const double* u, double plate_z, double ds, double* F, std::int8_t* state,
                    double* sgn) const noexcept {
        const std::size_t n = n_;
        const double r = r_;
        for (std::size_t i = 0; i < n; ++i) {
            const double lt = lam[i], ln = lam[n + i];
            const double g = plate_z - (z0_[i] + u[n + i]);
            const double w = (u[i] - uy_prev_[i]) - ds;
            const double an = ln - r * g;
            const bool act = an > 0;
            const double b = mu_node_[i] * (act ? an : 0.0);
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

    // Prepare the system of the piece (state, sign): reuse the factors when they are
    // of this piece; else, when the piece differs from the factored base piece by at
    // most kMaxBorder unknowns / equations, border the base (update_piece); else
    // factor it afresh (refactor_piece). Returns 0 or the 1-based row of a zero pivot.
    int factor_piece(const std::int8_t* state, const double* sign) noexcept {
        const std::size_t n = n_;
        for (std::size_t i = 0; i < n; ++i)
            slip_coef_[i] = state[i] == kContactSlip ? mu_node_[i] * sign[i] : 0.0;
        if (lu_valid_) {
            bool same = true;
            for (std::size_t i = 0; i < n && same; ++i)
                same = key_state_[i] == state[i] && key_coef_[i] == slip_coef_[i];
            if (same) return 0;
            if (update_piece(state) || (extend_base(state) && update_piece(state))) {
                copy8(state, key_state_.data());
                copy(slip_coef_.data(), key_coef_.data());
                ++n_updates_;
                ++piece_id_;
                return 0;
            }
        }
        return refactor_piece(state);
    }

    // Factor the piece (state, slip_coef_) as the new base, no border.
    int refactor_piece(const std::int8_t* state) noexcept {
        const std::size_t n = n_;
        ++piece_id_;
        base_changing();
        std::size_t m = 0;
        for (std::size_t i = 0; i < n; ++i) pos_ln_[i] = pos_lt_[i] = -1;
        for (std::size_t i = 0; i < n; ++i)
            if (state[i] != kContactOpen) { bnode_[m] = i; bkind_[m] = 0; pos_ln_[i] = static_cast<long>(m++); }
        for (std::size_t i = 0; i < n; ++i)
            if (state[i] == kContactStick) { bnode_[m] = i; bkind_[m] = 1; pos_lt_[i] = static_cast<long>(m++); }
        mB_ = m;
        double* M = M_.data();
        // rows: g on the active nodes, then w on the stuck ones; columns: ln_A, lt_T
        for (std::size_t k = 0; k < m; ++k) {
            const double* c = C_.data() + eq_row(k) * n2_;
            double* mk = M + k * n2_;
            for (std::size_t j = 0; j < m; ++j) {
                const std::size_t i = bnode_[j];
                mk[j] = bkind_[j] ? c[i] : c[i] * slip_coef_[i] - c[n + i];
            }
        }
        ++n_factorizations_;
        const int info = lu_factor(M, m, n2_, piv_.data());
        if (info != 0) return info;
        copy8(state, key_state_.data());
        copy(slip_coef_.data(), key_coef_.data());
        copy8(state, base_state_.data());
        copy(slip_coef_.data(), base_coef_.data());
        lu_valid_ = true;
        ++piece_id_;
        return 0;
    }

    // Forces of the prepared piece for the plate at plate_z, slip increment ds.
    void solve_prepared(double plate_z, double ds, double* lam) noexcept { solve_prepared(plate_z, ds, lam, false, 0, 0); }

    // unit: the right-hand side is az on every contact equation and ay on every stick
    // equation (the response to a unit plate motion), instead of the plate's gaps.
    void solve_prepared(double plate_z, double ds, double* lam, bool unit, double az, double ay) noexcept {
        const std::size_t n = n_, m = mB_, nb = nB_;
        auto rhs_g = [&](std::size_t i) { return unit ? az : plate_z - z0_[i]; };
        auto rhs_w = [&](std::size_t i) { return unit ? ay : uy_prev_[i] + ds; };
        double* b = rhs_.data();
        double* c = by_.data();
        for (std::size_t k = 0; k < m; ++k) b[k] = bkind_[k] ? rhs_w(bnode_[k]) : rhs_g(bnode_[k]);
        for (std::size_t r = 0; r < nb; ++r) {
            const BorderRow& br = brow_[r];
            c[r] = br.kind == kAddG ? rhs_g(br.node) : (br.kind == kAddW ? rhs_w(br.node) : 0.0);
        }
        // the base solve of a unit right-hand side depends on the base only: kept
        // until the next refactorisation, so a unit response of a bordered piece costs
        // O(m nb) besides its compliance product
        const int which = !unit ? -1 : (az == 1.0 && ay == 0.0 ? 0 : (az == 0.0 && ay == 1.0 ? 1 : -1));
        if (which >= 0) {
            double* zc = zunit_.data() + static_cast<std::size_t>(which) * n2_;
            if (!zunit_valid_[which]) {
                lu_solve(M_.data(), m, n2_, piv_.data(), b);
                copy(b, zc, m);
                zunit_valid_[which] = true;
            } else {
                copy(zc, b, m);
            }
            solve_bordered(b, c, lam, true);
        } else {
            solve_bordered(b, c, lam, false);
        }
        (void)n;
    }

    // Forces and displacements of the piece (state, sign) for the plate at (plate_y,
    // plate_z). Within one piece the response is affine in the plate position (the
    // stick equations' right-hand side uy_prev + ds = (uy_prev - s_prev) + plate_y
    // keeps uy_prev - s_prev while the nodes stay stuck), so the second time a piece
    // is met its responses to unit plate motions are solved, and from then on a step
    // of the same piece costs O(n): the reference solution plus the plate's moves
    // times the unit responses. Any change of the piece, or of uy_prev - s_prev on its
    // stuck nodes beyond round-off, starts over.
    int piece_response(const std::int8_t* state, const double* sign, double plate_z, double plate_y, double ds,
                       double* lam, double* u) noexcept {
        const int info = factor_piece(state, sign);
        if (info != 0) return info;
        if (aff_stage_ > 0 && aff_piece_ == piece_id_ && stick_offsets_unchanged()) {
            const double dz = plate_z - aff_z_, dy = plate_y - aff_y_;
            if (aff_stage_ == 1 && (dz != 0.0 || dy != 0.0)) {
                solve_prepared(0.0, 0.0, aff_lz_.data(), true, 1.0, 0.0);
                piece_displacement(aff_lz_.data(), aff_uz_.data(), true, 1.0, 0.0, 0.0, 0.0);
                solve_prepared(0.0, 0.0, aff_ly_.data(), true, 0.0, 1.0);
                piece_displacement(aff_ly_.data(), aff_uy_.data(), true, 0.0, 1.0, 0.0, 0.0);
                aff_stage_ = 2;
            }
            if (aff_stage_ == 2) {
                for (std::size_t i = 0; i < n2_; ++i) {
                    lam[i] = aff_lam_[i] + dz * aff_lz_[i] + dy * aff_ly_[i];
                    u[i] = aff_u_[i] + dz * aff_uz_[i] + dy * aff_uy_[i];
                }
            } else {
                copy(aff_lam_.data(), lam, n2_);
                copy(aff_u_.data(), u, n2_);
            }
            for (std::size_t i = 0; i < n_; ++i)  // exact zeros stay exact
                if (key_state_[i] == kContactOpen) lam[i] = lam[n_ + i] = 0.0;
            ++n_affine_;
            return 0;
        }
        solve_prepared(plate_z, ds, lam);
        piece_displacement(lam, u, false, 0.0, 0.0, plate_z, ds);
        copy(lam, aff_lam_.data(), n2_);
        copy(u, aff_u_.data(), n2_);
        aff_z_ = plate_z;
        aff_y_ = plate_y;
        for (std::size_t i = 0; i < n_; ++i) aff_v_[i] = uy_prev_[i] - s_prev_;
        aff_piece_ = piece_id_;
        aff_stage_ = 1;
        return 0;
    }

    // x of the prepared piece for right-hand sides b (base equations, overwritten) and
    // c (border rows, overwritten), as forces lam (2n).
    void solve_bordered(double* b, double* c, double* lam, bool base_solved = false) noexcept {
        const std::size_t n = n_, m = mB_, nb = nB_;
        double* z = b;
        if (!base_solved) {
            // The iterations of one point (the active-set steps of a solve, the rounds of a
            // breakaway cascade) border the same base with the same right-hand side: its
            // base solve is kept and reused while both are unchanged (the same bits)
            if (rhs_valid_ && std::memcmp(rhs_in_.data(), b, m * sizeof(double)) == 0) {
                copy(rhs_out_.data(), z, m);
                ++n_rhs_reused_;
            } else {
                copy(b, rhs_in_.data(), m);
                lu_solve(M_.data(), m, n2_, piv_.data(), z);
                copy(z, rhs_out_.data(), m);
                rhs_valid_ = true;
            }
        }
        double* y = c;
        if (nb > 0) {  // Schur complement: S y = c - W^T M0^-1 b, x = M0^-1 b - (M0^-1 V) y
            for (std::size_t r = 0; r < nb; ++r) y[r] -= border_row_dot(r, z);
            lu_solve(S_.data(), nb, kMaxBorder, spiv_.data(), y);
            // (the columns' addresses from their slots: a kernel copied from another
            // (a pad's shadow ridge detached from its master) has its own cache)
            for (std::size_t c = 0; c < nb; ++c) vcol_[c] = vcache_.data() + vslot_[c] * n2_;
            sub_columns(z, m, vcol_.data(), y, nb);
        }
        for (std::size_t i = 0; i < n2_; ++i) lam[i] = 0.0;
        // base unknowns (those fixed to zero by the border come out as ~zero and are
        // overwritten below)
        for (std::size_t k = 0; k < m; ++k) lam[bkind_[k] ? bnode_[k] : n + bnode_[k]] = z[k];
        for (std::size_t col = 0; col < nb; ++col) {
            const BorderCol& bc = bcol_[col];
            if (bc.kind == kAddLn) lam[n + bc.node] = y[col];
            else if (bc.kind == kAddLt) lam[bc.node] = y[col];
        }
        for (std::size_t i = 0; i < n; ++i) {
            if (key_state_[i] == kContactSlip) lam[i] = key_coef_[i] * lam[n + i];  // lt = mu sign ln
            else if (key_state_[i] == kContactOpen) lam[i] = lam[n + i] = 0.0;     // exactly, not ~0 from the border
        }
    }

    // The stuck nodes' offsets uy_prev - s_prev are those of the affine reference.
    // Within one piece they are unchanged in exact arithmetic (w = 0 on a stuck node);
    // what changes is the round-off of u_y, about 1e-19 m. The test is relative to the
    // step's length scale (the indent, or the largest tangential displacement): a
    // difference of 1e-13 of it moves the forces by about 1e-13 relative, far below
    // the solver tolerance, while a history that really differs (set_history, a
    // stuck node that slid meanwhile) is caught.
    bool stick_offsets_unchanged() const noexcept {
        const double tol = 1e-13 * scale_len_;
        for (std::size_t i = 0; i < n_; ++i) {
            if (key_state_[i] != kContactStick) continue;
            const double v = uy_prev_[i] - s_prev_, ref = aff_v_[i];
            if (std::fabs(v - ref) > tol) return false;
        }
        return true;
    }

    int solve_piece(const std::int8_t* state, const double* sign, double plate_z, double ds, double* lam) noexcept {
        const int info = factor_piece(state, sign);
        if (info != 0) return info;
        solve_prepared(plate_z, ds, lam);
        return 0;
    }

    // Generalised Jacobian of the Alart-Curnier residual for the classification
    // (state, sign) into J (2n x 2n, row-major).
    void jacobian(const std::int8_t* state, const double* sign, double* J) const noexcept {
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
                const double ms = mu_node_[i] * sign[i];
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

private:
    template <typename V, typename T>
    static void fillv(V& v, T x) noexcept { for (auto& e : v) e = x; }
    static void fill(std::vector<double>& v, double x) noexcept { fillv(v, x); }
    static void fill8(std::vector<std::int8_t>& v, std::int8_t x) noexcept { fillv(v, x); }
    static void fill8(std::vector<std::uint8_t>& v, std::uint8_t x) noexcept { fillv(v, x); }
    void copy(const double* a, double* b) const noexcept { copy(a, b, n_); }
    static void copy(const double* a, double* b, std::size_t m) noexcept { for (std::size_t i = 0; i < m; ++i) b[i] = a[i]; }
    void copy8(const std::int8_t* a, std::int8_t* b) const noexcept { for (std::size_t i = 0; i < n_; ++i) b[i] = a[i]; }

    // ---- bordered update of the base factorisation
    //
    // The base piece P0 (unknowns ln_A0, lt_T0; equations g_A0, w_T0) is factored in
    // M_. A nearby piece P1 is solved as the bordered system
    //     [M0  V] [x]   [b]
    //     [W^T Z] [y] = [c]
    // with one border row and column per difference: an unknown of P0 that P1 lacks
    // (or whose slip coefficient changed) is fixed to zero by a row e_j; an equation
    // of P0 that P1 lacks is voided by a slack column e_i; an unknown / equation of P1
    // that P0 lacks (or the changed unknown's new version) is a column / row. The
    // Schur complement S = Z - W^T M0^-1 V (at most kMaxBorder square) is factored;
    // M0^-1 V is kept, so a solve is one base solve and O(m nb) more.
    //
    // A node stuck in P0 that slides in P1 (the common change while the slip front
    // moves) keeps both its unknowns: its stick equation w_i is voided by a slack
    // column and the slip law lt_i - mu s ln_i = 0 is added as a row over the base
    // unknowns (kSlipRow). That is two borders, where fixing lt_i and replacing the
    // ln_i column by its slip version would take four, so twice as many nodes may
    // break away before the base is refactored.
    enum : std::uint8_t { kFix = 0, kAddG = 1, kAddW = 2, kAddLn = 3, kAddLt = 4, kSlack = 5, kSlipRow = 6 };
    struct BorderRow { std::uint8_t kind; std::size_t node; std::size_t pos; };
    struct BorderCol { std::uint8_t kind; std::size_t node; std::size_t pos; };
    // 64: a gross slip slides the stuck nodes a few at a time, two borders each; 16
    // refactored every eighth node (on the open-loop pad paths 2002 factorisations in
    // 3000 ticks, 200 with 64; the border's rows and columns kept from one piece to the
    // next keep the larger border's updates cheap)
    static constexpr std::size_t kMaxBorder = 64;
    static constexpr std::size_t kColCache = 2 * kMaxBorder;
    struct CachedCol { std::uint8_t kind; std::size_t node; std::size_t pos; double coef; };

    // The base factors are about to change (refactor_piece, extend_base): they are not valid
    // until the change succeeds, and the border and every solve kept with the old base (the
    // M0^-1 V columns, the unit and load right-hand sides' base solves) are forgotten.
    void base_changing() noexcept {
        lu_valid_ = false;
        nB_ = 0;
        n_cached_ = 0;
        onb_ = 0;
        s_lu_ok_ = false;
        zunit_valid_[0] = zunit_valid_[1] = false;
        rhs_valid_ = false;
    }

    std::size_t eq_row(std::size_t k) const noexcept {  // C row of base equation k
        return bkind_[k] ? bnode_[k] : n_ + bnode_[k];
    }
    // Border row r of W^T (Wt_) against x (length mB_). The rows of the force laws are
    // zero but at one entry (kFix: the unknown fixed to zero) or two (kSlipRow: lt_i and
    // ln_i), so they cost those entries, not a dot product over the base: with the
    // slip front moving, most border rows are of this kind, and the dot products were
    // a bordered solve's largest cost after its base solve.
    double border_row_dot(std::size_t r, const double* x) const noexcept {
        const BorderRow& br = brow_[r];
        const double* w = Wt_.data() + r * n2_;
        if (br.kind == kFix) return w[br.pos] * x[br.pos];
        if (br.kind == kSlipRow) {
            const std::size_t q = static_cast<std::size_t>(pos_ln_[br.node]);
            return w[br.pos] * x[br.pos] + w[q] * x[q];
        }
        return dot(w, x, mB_);
    }
    // coefficient of unknown (ln_i with slip coefficient coef, or lt_i) in C row r
    double coef_ln(std::size_t r, std::size_t i, double coef) const noexcept {
        const double* c = C_.data() + r * n2_;
        return c[i] * coef - c[n_ + i];
    }
    double coef_lt(std::size_t r, std::size_t i) const noexcept { return C_[r * n2_ + i]; }
    // coefficient of base unknown k in C row r
    double base_coef(std::size_t r, std::size_t k) const noexcept {
        const std::size_t i = bnode_[k];
        return bkind_[k] ? coef_lt(r, i) : coef_ln(r, i, base_coef_[i]);
    }

    // Per-node chains over entries e[0, count) (border rows, border columns, cached
    // columns: anything with a .node): head[node] is the first entry of that node, next[q]
    // the one after q (-1: none), in increasing order. unlink_chains resets the heads it
    // set, so the heads are all -1 between uses (O(count), not O(n)) and one head array
    // serves every chain in turn.
    template <class E>
    static void link_chains(const E* e, std::size_t count, long* head, long* next) noexcept {
        for (std::size_t q = count; q-- > 0;) {
            next[q] = head[e[q].node];
            head[e[q].node] = static_cast<long>(q);
        }
    }
    template <class E>
    static void unlink_chains(const E* e, std::size_t count, long* head) noexcept {
        for (std::size_t q = 0; q < count; ++q) head[e[q].node] = -1;
    }

    // Border the base for the piece (state, slip_coef_); false if it needs more than
    // kMaxBorder borders or its Schur complement is singular (then refactor).
    bool update_piece(const std::int8_t* state) noexcept {
        const std::size_t n = n_, m = mB_;
        std::size_t nr = 0, nc = 0;
        auto add_row = [&](std::uint8_t kind, std::size_t node, std::size_t pos) {
            if (nr < kMaxBorder) brow_[nr] = {kind, node, pos};
            ++nr;
        };
        auto add_col = [&](std::uint8_t kind, std::size_t node, std::size_t pos) {
            if (nc < kMaxBorder) bcol_[nc] = {kind, node, pos};
            ++nc;
        };
        for (std::size_t i = 0; i < n; ++i) {
            const std::int8_t s0 = base_state_[i], s1 = state[i];
            const bool a0 = s0 != kContactOpen, a1 = s1 != kContactOpen;
            const bool t0 = s0 == kContactStick, t1 = s1 == kContactStick;
            if (t0 && s1 == kContactSlip) {  // stuck in the base, sliding now: the slip law as a row
                add_row(kSlipRow, i, static_cast<std::size_t>(pos_lt_[i]));
                add_col(kSlack, i, static_cast<std::size_t>(pos_lt_[i]));  // w_i is base equation pos_lt
                if (nr > kMaxBorder || nc > kMaxBorder) return false;
                continue;
            }
            const bool same_ln = a0 && a1 && base_coef_[i] == slip_coef_[i];
            if (a0 && !same_ln) add_row(kFix, i, static_cast<std::size_t>(pos_ln_[i]));
            if (a1 && !same_ln) add_col(kAddLn, i, 0);
            if (t0 && !t1) add_row(kFix, i, static_cast<std::size_t>(pos_lt_[i]));
            if (t1 && !t0) add_col(kAddLt, i, 0);
            if (a0 && !a1) add_col(kSlack, i, static_cast<std::size_t>(pos_ln_[i]));  // g_i is base equation pos_ln
            if (a1 && !a0) add_row(kAddG, i, 0);
            if (t0 && !t1) add_col(kSlack, i, static_cast<std::size_t>(pos_lt_[i]));  // w_i is base equation pos_lt
            if (t1 && !t0) add_row(kAddW, i, 0);
            if (nr > kMaxBorder || nc > kMaxBorder) return false;
        }
        if (nr != nc) return false;  // cannot happen (both pieces are square); be safe
        const std::size_t nb = nr;
        const std::size_t K = kMaxBorder;
        auto row_coef = [&](const BorderRow& br) { return br.kind == kSlipRow ? slip_coef_[br.node] : 0.0; };
        auto col_coef = [&](const BorderCol& bc) { return bc.kind == kAddLn ? slip_coef_[bc.node] : 0.0; };
        // where a border row (column) of this piece was one of the last piece's, with the
        // same coefficient: its entries are kept (-1: new)
        // (found through per-node chains of the old entries: a node has at most two
        // border rows and two columns, so a lookup is a step or two; a scan of the last
        // border costs a fifth of a bordered update's own time on the open-loop paths)
        long* head = node_head_.data();
        auto kept = [&](const auto& b, double coef, const auto& old, const auto& old_coef) -> long {
            for (long q = head[b.node]; q >= 0; q = chain_next_[static_cast<std::size_t>(q)])
                if (old[q].kind == b.kind && old[q].pos == b.pos && old_coef[q] == coef) return q;
            return -1;
        };
        link_chains(obrow_.data(), onb_, head, chain_next_.data());
        for (std::size_t r = 0; r < nb; ++r) rmap_[r] = kept(brow_[r], row_coef(brow_[r]), obrow_, orcoef_);
        unlink_chains(obrow_.data(), onb_, head);
        link_chains(obcol_.data(), onb_, head, chain_next_.data());
        for (std::size_t c = 0; c < nb; ++c) cmap_[c] = kept(bcol_[c], col_coef(bcol_[c]), obcol_, occoef_);
        unlink_chains(obcol_.data(), onb_, head);
        // (the rows of the force laws are read at their one or two entries only,
        // border_row_dot: the others are not written)
        // when every row and column of the last border is kept (nodes added to the
        // border, none taken off: a cascade sliding its nodes a few at a time), they
        // go first in their old order and the factors of the last S are extended by
        // the new rows and columns (extend_s), O(nb^2 k) for k new ones instead of O(nb^3)
        std::size_t kept_r = 0, kept_c = 0;
        for (std::size_t r = 0; r < nb; ++r) kept_r += rmap_[r] >= 0;
        for (std::size_t c = 0; c < nb; ++c) kept_c += cmap_[c] >= 0;
        const bool extend = s_lu_ok_ && onb_ > 0 && kept_r == onb_ && kept_c == onb_;  // (so nb >= onb_)
        if (extend) {
            std::size_t qr = onb_, qc = onb_;
            for (std::size_t r = 0; r < nb; ++r) {
                const std::size_t d = rmap_[r] >= 0 ? static_cast<std::size_t>(rmap_[r]) : qr++;
                trow_[d] = brow_[r];
            }
            for (std::size_t c = 0; c < nb; ++c) {
                const std::size_t d = cmap_[c] >= 0 ? static_cast<std::size_t>(cmap_[c]) : qc++;
                tcol_[d] = bcol_[c];
            }
            for (std::size_t r = 0; r < nb; ++r) {
                brow_[r] = trow_[r];
                bcol_[r] = tcol_[r];
                rmap_[r] = cmap_[r] = r < onb_ ? static_cast<long>(r) : -1;
            }
        }
        // M0^-1 V: columns already solved for this base (the same border column of an
        // earlier nearby piece) come from the column cache; the others are gathered to
        // the front of vnew_ and solved together (one pass over the factors for all)
        std::size_t nnew = 0;
        for (std::size_t q = 0; q < kColCache; ++q) slot_used_[q] = 0;
        link_chains(ccol_.data(), n_cached_, head, cache_next_.data());
        for (std::size_t c = 0; c < nb; ++c) {
            const BorderCol& bc = bcol_[c];
            const double coef = col_coef(bc);
            std::size_t hit = kColCache;
            for (long q = head[bc.node]; q >= 0; q = cache_next_[static_cast<std::size_t>(q)]) {
                const CachedCol& cc = ccol_[static_cast<std::size_t>(q)];
                if (cc.kind == bc.kind && cc.pos == bc.pos && cc.coef == coef) { hit = static_cast<std::size_t>(q); break; }
            }
            if (hit < kColCache) {  // the border reads the cached column in place
                vcol_[c] = vcache_.data() + hit * n2_;
                vslot_[c] = hit;
                slot_used_[hit] = 1;
                continue;
            }
            double* w = vnew_.data() + nnew * n2_;
            for (std::size_t k = 0; k < m; ++k) {
                if (bc.kind == kSlack) w[k] = k == bc.pos ? 1.0 : 0.0;
                else if (bc.kind == kAddLn) w[k] = coef_ln(eq_row(k), bc.node, coef);
                else w[k] = coef_lt(eq_row(k), bc.node);
            }
            new_col_[nnew++] = c;
        }
        unlink_chains(ccol_.data(), n_cached_, head);
        if (nnew > 0) lu_solve(M_.data(), m, n2_, piv_.data(), vnew_.data(), n2_, nnew);
        // the new columns go to free slots of the cache, or replace columns this border
        // does not use (kColCache >= 2 kMaxBorder: there is always one)
        for (std::size_t q = 0; q < nnew; ++q) {
            const std::size_t c = new_col_[q];
            const BorderCol& bc = bcol_[c];
            const double coef = col_coef(bc);
            std::size_t slot;
            if (n_cached_ < kColCache) {
                slot = n_cached_++;
            } else {
                do slot = next_slot_++ % kColCache; while (slot_used_[slot]);
            }
            slot_used_[slot] = 1;
            ccol_[slot] = {bc.kind, bc.node, bc.pos, coef};
            double* v = vcache_.data() + slot * n2_;
            std::memcpy(v, vnew_.data() + q * n2_, m * sizeof(double));
            vcol_[c] = v;
            vslot_[c] = slot;
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
        // the leading onb_ x onb_ block of S stay where they are, only the new rows of
        // W^T and the new rows and columns of S are written. Else both are rebuilt into
        // the spare buffers, the kept entries copied from their old places.
        const std::size_t r0 = extend ? onb_ : 0;
        n_border_ext_ += extend;
        double* wt = extend ? Wt_.data() : Wt2_.data();
        double* sb = extend ? S0_.data() : S1_.data();
        for (std::size_t r = r0; r < nb; ++r) {
            const BorderRow& br = brow_[r];
            double* w = wt + r * n2_;
            if (br.kind == kFix) {
                w[br.pos] = law;
            } else if (br.kind == kSlipRow) {  // lt_i - mu s ln_i (ln_i has slip coefficient 0 in the base)
                w[br.pos] = law;
                w[static_cast<std::size_t>(pos_ln_[br.node])] = -slip_coef_[br.node] * law;
            } else if (rmap_[r] >= 0) {
                std::memcpy(w, Wt_.data() + static_cast<std::size_t>(rmap_[r]) * n2_, m * sizeof(double));
            } else {
                const std::size_t row = br.kind == kAddG ? n + br.node : br.node;
                for (std::size_t k = 0; k < m; ++k) w[k] = base_coef(row, k);
            }
        }
        if (!extend) Wt_.swap(Wt2_);
        for (std::size_t r = 0; r < nb; ++r) {
            const BorderRow& br = brow_[r];
            double* srow = sb + r * K;
            const double* orow = rmap_[r] >= 0 ? S0_.data() + static_cast<std::size_t>(rmap_[r]) * K : nullptr;
            for (std::size_t c = r < r0 ? r0 : 0; c < nb; ++c) {
                if (orow && cmap_[c] >= 0) {
                    srow[c] = orow[cmap_[c]];
                    continue;
                }
                const BorderCol& bc = bcol_[c];
                double z = 0.0;
                if (br.kind != kFix && br.kind != kSlipRow && bc.kind != kSlack) {
                    const std::size_t row = br.kind == kAddG ? n + br.node : br.node;
                    z = bc.kind == kAddLn ? coef_ln(row, bc.node, slip_coef_[bc.node]) : coef_lt(row, bc.node);
                }
                srow[c] = z - border_row_dot(r, vcol_[c]);
            }
        }
        if (!extend) S0_.swap(S1_);
        const std::size_t nb0 = onb_;
        for (std::size_t r = 0; r < nb; ++r) {
            obrow_[r] = brow_[r];
            orcoef_[r] = row_coef(brow_[r]);
            obcol_[r] = bcol_[r];
            occoef_[r] = col_coef(bcol_[r]);
        }
        onb_ = nb;
        nB_ = nb;
        const bool ok = extend ? extend_s(nb0, nb) : factor_s(nb);
        s_lu_ok_ = ok;
        if (!ok) nB_ = 0;
        return ok;
    }

    // LU of the border's Schur complement S0_ (nb square, ld kMaxBorder) into S_.
    bool factor_s(std::size_t nb) noexcept {
        const std::size_t K = kMaxBorder;
        for (std::size_t r = 0; r < nb; ++r) copy(S0_.data() + r * K, S_.data() + r * K, nb);
        return nb == 0 || lu_factor(S_.data(), nb, K, spiv_.data()) == 0;
    }

    // S_ holds the factors of S0_'s leading nb0 x nb0 block (the last border's S):
    // extend them to all of S0_ (nb square), as extend_base extends the base: with
    // P0 S00 = L0 U0, the new columns through P0 and L0 (Y), the new rows through U0
    // (X), and the LU of Z - X Y with partial pivoting within the new block.
    bool extend_s(std::size_t nb0, std::size_t nb) noexcept {
        const std::size_t K = kMaxBorder, k = nb - nb0;
        if (k == 0) return true;
        double* S = S_.data();
        const double* S0 = S0_.data();
        double* t = vnew_.data();  // the new columns, column-major (ld K)
        for (std::size_t c = 0; c < k; ++c)
            for (std::size_t r = 0; r < nb0; ++r) t[c * K + r] = S0[r * K + nb0 + c];
        if (nb0 > 0) lu_forward(S, nb0, K, spiv_.data(), t, K, k);
        for (std::size_t c = 0; c < k; ++c)
            for (std::size_t r = 0; r < nb0; ++r) S[r * K + nb0 + c] = t[c * K + r];
        for (std::size_t r = nb0; r < nb; ++r) copy(S0 + r * K, S + r * K, nb);
        if (nb0 > 0) lu_right_upper(S, nb0, K, S + nb0 * K, K, k);
        return finish_extension(S, K, nb0, k, spiv_.data());
    }

    // The last step of extending an LU (P0 A00 = L0 U0, leading m0 x m0 of A, ld lda) by k
    // rows and columns, as extend_base and extend_s do: A's new rows hold X (through U0)
    // left of the new block and Z in it, its new columns Y (through P0 and L0) above it.
    // S = Z - X Y goes into the new block, then its LU with partial pivoting within the
    // block (pivots piv[m0..m0+k), offset to whole rows); its row swaps apply to X too.
    static bool finish_extension(double* A, std::size_t lda, std::size_t m0, std::size_t k, int* piv) noexcept {
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

    // Append to the base the nodes the piece (state, slip_coef_) touches and the base
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
    bool extend_base(const std::int8_t* state) noexcept {
        const std::size_t n = n_, n2 = n2_, m = mB_;
        std::size_t rows = 0, add = 0;  // border rows of the other differences; positions to append
        for (std::size_t i = 0; i < n; ++i) {
            const std::int8_t s0 = base_state_[i], s1 = state[i];
            const bool a0 = s0 != kContactOpen, a1 = s1 != kContactOpen;
            const bool t0 = s0 == kContactStick, t1 = s1 == kContactStick;
            if (!a0 && a1) { add += t1 ? 2 : 1; continue; }
            if (t0 && s1 == kContactSlip) { ++rows; continue; }
            const bool same_ln = a0 && a1 && base_coef_[i] == slip_coef_[i];
            rows += (a0 && !same_ln) + (t0 && !t1) + (t1 && !t0);
        }
        if (add == 0 || rows > kMaxBorder) return false;
        const std::size_t me = m + add;
        for (std::size_t i = 0, q = m; i < n; ++i) {
            if (base_state_[i] != kContactOpen || state[i] == kContactOpen) continue;
            bnode_[q] = i; bkind_[q] = 0; pos_ln_[i] = static_cast<long>(q++);
            if (state[i] == kContactStick) { bnode_[q] = i; bkind_[q] = 1; pos_lt_[i] = static_cast<long>(q++); }
            base_state_[i] = state[i];
            base_coef_[i] = slip_coef_[i];
        }
        // from here on the base is changed: a failure must refactor
        base_changing();
        double* M = M_.data();
        // Y: the new columns over the base equations, through P0 and L0, in chunks of
        // kMaxBorder columns gathered into vnew_
        for (std::size_t c0 = m; c0 < me; c0 += kMaxBorder) {
            const std::size_t kc = me - c0 < kMaxBorder ? me - c0 : kMaxBorder;
            for (std::size_t c = 0; c < kc; ++c) {
                double* v = vnew_.data() + c * n2;
                for (std::size_t k = 0; k < m; ++k) v[k] = base_coef(eq_row(k), c0 + c);
            }
            lu_forward(M, m, n2, piv_.data(), vnew_.data(), n2, kc);
            for (std::size_t c = 0; c < kc; ++c) {
                const double* v = vnew_.data() + c * n2;
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
        if (!finish_extension(M, n2, m, add, piv_.data())) return false;
        mB_ = me;
        lu_valid_ = true;
        ++n_extensions_;
        ++piece_id_;
        return true;
    }

    // The damped semismooth Newton method on F from the committed forces, result in
    // c_lam_ / c_u_ (the classification is redone by the caller).
    ContactStatus damped_newton(double plate_z, double ds, double atol, int& it) noexcept {
        const std::size_t n2 = n2_;
        double* lam = c_lam_.data();
        double* u = c_u_.data();
        copy(lam_.data(), lam, n2);
        displacement(lam, u);
        double* F = F_.data();
        std::int8_t* st = ws_state_.data();
        double* sg = ws_sign_.data();
        double norm = classify(lam, u, plate_z, ds, F, st, sg);
        it = 0;
        while (norm > atol) {
            if (it >= params.max_iter) {
                err_residual_ = norm; err_atol_ = atol; err_info_ = params.max_iter;
                return ContactStatus::no_convergence;
            }
            jacobian(st, sg, J_.data());
            double merit = 0.0;
            for (std::size_t i = 0; i < n2; ++i) { d_[i] = -F[i]; merit += F[i] * F[i]; }
            if (lu_factor(J_.data(), n2, n2, jpiv_.data()) != 0) {
                err_info_ = it;
                return ContactStatus::singular_jacobian;
            }
            lu_solve(J_.data(), n2, n2, jpiv_.data(), d_.data());
            double t = 1.0;
            double* F2 = F2_.data();
            std::int8_t* st2 = ws_state2_.data();
            double* sg2 = ws_sign2_.data();
            double norm2 = 0.0;
            while (true) {
                for (std::size_t i = 0; i < n2; ++i) lam2_[i] = lam[i] + t * d_[i];
                displacement(lam2_.data(), u2_.data());
                norm2 = classify(lam2_.data(), u2_.data(), plate_z, ds, F2, st2, sg2);
                double m2 = 0.0;
                for (std::size_t i = 0; i < n2; ++i) m2 += F2[i] * F2[i];
                if (m2 <= (1 - 1e-4 * t) * merit || t < 1e-6) break;
                t *= 0.5;
            }
            copy(lam2_.data(), lam, n2);
            copy(u2_.data(), u, n2);
            copy(F2, F, n2);
            for (std::size_t i = 0; i < n_; ++i) { st[i] = st2[i]; sg[i] = sg2[i]; }
            norm = norm2;
            ++it;
        }
        return ContactStatus::ok;
    }

    std::size_t n_, n2_;
    std::vector<double> C_, z0_, w_;
    double w_tol_, r_ = 0.0, z0_max_ = 0.0;
    double scale_len_ = 1e-9;  // the length scale of the current step (m), see stick_offsets_unchanged
    std::size_t argmax_z0_ = 0;
    // committed history
    std::vector<double> lam_, uy_prev_, sign_;
    std::vector<std::int8_t> state_;
    std::vector<std::uint8_t> sliding_;
    double s_prev_ = 0.0;
    // candidate
    std::vector<double> c_lam_, c_u_, c_sign_, c_forces_;
    std::vector<std::int8_t> c_state_, c_reported_;
    double c_frac_ = 0.0, c_plate_y_ = 0.0;
    int c_iterations_ = 0;
    bool has_candidate_ = false;
    // friction coefficients the current state was solved with (settle_friction)
    double fr_mu_ = 0.0, fr_muk_ = 0.0, sv_fr_mu_ = 0.0, sv_fr_muk_ = 0.0;
    // workspaces
    std::vector<double> mu_node_, F_, F2_, u2_, lam2_, d_, ws_sign_, ws_sign2_, rhs_, M_, J_, slip_coef_, key_coef_;
    std::vector<std::int8_t> ws_state_, ws_state2_, key_state_;
    std::vector<double> plam_;  // P lam (piece_displacement)
    std::vector<std::size_t> free_rows_;
    std::vector<int> piv_, jpiv_;
    // the base piece's unknowns / equations: position k is ln (kind 0, with equation
    // g) or lt (kind 1, with equation w) of node bnode_[k]; mB_ of them
    std::vector<std::size_t> bnode_;
    std::vector<std::uint8_t> bkind_;
    std::size_t mB_ = 0;
    long n_extensions_ = 0;
    long n_border_ext_ = 0;
    // base piece and its border
    std::vector<long> pos_ln_, pos_lt_;
    std::vector<std::int8_t> base_state_;
    std::vector<double> base_coef_, Wt_, S_, by_, vnew_;
    std::vector<std::size_t> vslot_;   // M0^-1 V: column c of the border is slot vslot_[c] of vcache_
    std::vector<const double*> vcol_;  // its address (set where it is used)
    std::vector<std::uint8_t> slot_used_;
    std::vector<std::size_t> new_col_;
    std::vector<int> spiv_;
    std::vector<BorderRow> brow_;
    std::vector<BorderCol> bcol_;
    std::size_t nB_ = 0;
    // the last border's rows and columns (with their coefficients), its W^T rows and its
    // Schur complement before factoring (ld kMaxBorder), kept with the base (update_piece)
    std::vector<BorderRow> obrow_;
    std::vector<BorderCol> obcol_;
    std::vector<double> orcoef_, occoef_, Wt2_, S0_, S1_;
    std::vector<long> rmap_, cmap_;
    std::vector<long> node_head_;  // per node: the first entry of its chain (-1 between uses)
    std::vector<long> chain_next_, cache_next_;  // the chains of the last border's entries, of the cached columns
    std::size_t onb_ = 0;
    bool s_lu_ok_ = false;  // S_ holds the factors of the last border's S (extend_s may extend them)
    std::vector<BorderRow> trow_;
    std::vector<BorderCol> tcol_;
    long n_updates_ = 0;
    std::vector<double> vcache_;
    std::vector<CachedCol> ccol_;
    std::size_t n_cached_ = 0, next_slot_ = 0;
    // affine response of the current piece (piece_response)
    std::vector<double> aff_lam_, aff_u_, aff_lz_, aff_uz_, aff_ly_, aff_uy_, aff_v_;
    double aff_z_ = 0.0, aff_y_ = 0.0;
    long piece_id_ = 0, aff_piece_ = -1, n_affine_ = 0;
    int aff_stage_ = 0;
    bool lu_valid_ = false;
    long err_info_ = 0;
    long n_factorizations_ = 0;
    double err_residual_ = 0.0, err_atol_ = 0.0;
    // path following (follow): displacements of the current state, the plate height,
    // the end of the current piece, the unit responses and their key, the events of a
    // point, the cascade's previous statuses, the saved history and the outputs
    std::vector<double> pu_, pl1_, pu1_, rs_, rz_, us_, uz_, ukey_sign_, ev_frac_, prev_sign_;
    std::vector<double> sv_lam_, sv_u_, sv_sign_, o_lam_, o_u_, zunit_;
    bool zunit_valid_[2] = {false, false};  // base solves of the unit right-hand sides (solve_prepared)
    // the last base solve of a load's right-hand side (solve_bordered): input and solution
    std::vector<double> rhs_in_, rhs_out_;
    bool rhs_valid_ = false;
    long n_rhs_reused_ = 0;
    std::vector<std::int8_t> ukey_state_, ev_kind_, prev_state_, sv_state_;
    std::vector<std::size_t> ev_node_;
    static constexpr std::size_t kSeenCap = 256;  // status sets kept per point (more: status_cycle)
    std::vector<std::int8_t> seen_, key_;
    std::vector<bool> seen_resolved_;
    std::size_t n_seen_ = 0;
    double z_prev_ = 0.0, sv_s_ = 0.0, sv_z_ = 0.0, ukey_mu_ = 0.0, ukey_muk_ = 0.0;
    double g_tol_ = 0.0, f_tol_ = 0.0, evt_g_tol_ = 0.0, evt_f_tol_ = 0.0, err_y_ = 0.0, err_z_ = 0.0;
    std::vector<double> fl_lam_, fl_u_, fl_sign_;  // solve_load(exact): the first answer within tolerance
    std::vector<std::int8_t> fl_state_;
    bool has_z_ = false, sv_has_z_ = false, unit_valid_ = false, pristine_ = true, sv_pristine_ = true;
    long solves_ = 0, events_ = 0, sv_solves_ = 0, sv_events_ = 0;
    double* out_lam_ = nullptr;
    double* out_u_ = nullptr;
    std::int8_t* out_state_ = nullptr;
    std::size_t out_s2_ = 0, out_s1_ = 0, out_row0_ = 0;
    // projected outputs (set_projection, follow with Extra)
    std::size_t q_ = 0;
    std::vector<double> Pt_, pc_, pd_;
    Extra ex_;
};

}  // namespace tactile
