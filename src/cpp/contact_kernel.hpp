// ContactSolverKernel, the compiled contact solver of one ridge (contact_solver.hpp
// describes the algorithm): its interface, its parameters and results, and its state,
// grouped by role. The member functions of any length are defined beside it: the piece
// systems (factorisation, bordering, extension, solves) in contact_piece.hpp, the path
// following and the load-point solves in contact_path.hpp. Include contact_solver.hpp,
// which brings all three.
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
        for (std::size_t i = 1; i < n; ++i)
            if (z0_[i] > z0_max_) z0_max_ = z0_[i];
        lam_.assign(n2_, 0.0); uy_prev_.assign(n, 0.0); sign_.assign(n, 0.0); pu_.assign(n2_, 0.0);
        state_.assign(n, kContactOpen); sliding_.assign(n, 0);
        saved_.allocate(n); stepped_.allocate(n); solved_.allocate(n); act_.allocate(n); newton_.allocate(n);
        piece_.allocate(n); base_.allocate(n); border_.allocate(n); cols_.allocate(n); aff_.allocate(n);
        unit_.allocate(n); ev_.allocate(n); disp_.allocate(n);
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
        z_prev_ = 0.0; has_z_ = false; unit_.valid = false;
        solves_ = 0; events_ = 0;
        fill(lam_, 0.0); fill(uy_prev_, 0.0); fill(sign_, 0.0);
        fill8(state_, kContactOpen); fill8(sliding_, 0);
        s_prev_ = 0.0;
        base_.valid = false;
        aff_.stage = 0;
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
        const ContactStatus s = follow(&plate_y, &plate_z, 1, every, stepped_.lam.data(), stepped_.u.data(),
                                       stepped_.state.data(), 0, 0);
        if (s != ContactStatus::ok) return s;
        report(stepped_.lam.data(), stepped_.state.data(), stepped_.forces.data(), stepped_.slip_fraction);
        stepped_.iterations = static_cast<int>(solves_ - s0);
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

    // Solve the step to (plate_y, plate_z) with the cones act_.mu, from the
    // classification (st, sg) (which must be act_.state / act_.sign: they are used as
    // workspace): active-set iterations, then the damped Newton method if they cycle.
    // The result is in solved_.lam, solved_.u, solved_.state, solved_.sign; `it` counts the iterations.
    // exact: go on while the classification still changes, even once the residual is
    // within atol (the exact solution of its piece); if the pieces cycle, the first
    // answer within the tolerance.
    ContactStatus solve_load(std::int8_t* st, double* sg, double plate_z, double plate_y, double ds, double atol,
                             int& it, bool exact = false) noexcept;

    // ---- results of the last solve (valid after it returned ok; kept by commit)
    const double* forces() const noexcept { return stepped_.forces.data(); }        // (2n) f = (lt, -ln), N/m
    const double* displacement() const noexcept { return stepped_.u.data(); }       // (2n) (u_y, u_z), m
    const std::int8_t* reported_state() const noexcept { return stepped_.state.data(); }  // (n)
    double slip_fraction() const noexcept { return stepped_.slip_fraction; }
    int iterations() const noexcept { return stepped_.iterations; }
    // Piece factorisations since construction (a step that reuses the factors adds none).
    long factorizations() const noexcept { return stats_.factorizations; }
    // Pieces solved by bordering the factored base piece instead of refactoring.
    long updates() const noexcept { return stats_.updates; }
    // Times the base was extended by the nodes a piece added (extend_base) instead of
    // refactored.
    long extensions() const noexcept { return stats_.extensions; }
    // Bordered updates that kept every border row and column of the last one and added to
    // it (the border's W^T rows and Schur complement extended in place, extend_s).
    long border_extensions() const noexcept { return stats_.border_extensions; }
    // Piece solves served by the affine response of an unchanged piece (O(n) each).
    long affine_steps() const noexcept { return stats_.affine; }
    // Base solves of a load's right-hand side served by the last one (same base, same
    // right-hand side: the iterations of one point).
    long rhs_reuses() const noexcept { return stats_.rhs_reuses; }
    // ---- error details of the last failed solve
    long error_info() const noexcept { return err_.info; }
    double error_residual() const noexcept { return err_.residual; }
    double error_tolerance() const noexcept { return err_.atol; }

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
        aff_.stage = 0;
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
                         std::size_t out_stride1) noexcept;

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
        out_.q = q;
        out_.Pt.assign(q * n2_, 0.0);  // column-major: the q entries of column j together
        for (std::size_t a = 0; a < q; ++a)
            for (std::size_t j = 0; j < n2_; ++j) out_.Pt[j * q + a] = P[a * n2_ + j];
        out_.pc.assign(q, 0.0);
        out_.pd.assign(q, 0.0);
    }
    std::size_t projection_size() const noexcept { return out_.q; }
    ContactStatus follow(const double* ys, const double* zs, std::size_t N, bool every, double* lam_out,
                         double* u_out, std::int8_t* state_out, std::size_t out_stride2, std::size_t out_stride1,
                         const Extra& extra) noexcept {
        out_.extra = extra;
        if (!out_.q) out_.extra.proj = nullptr;
        const ContactStatus s = follow(ys, zs, N, every, lam_out, u_out, state_out, out_stride2, out_stride1);
        out_.extra = Extra{};
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
    double error_y() const noexcept { return err_.y; }
    double error_z() const noexcept { return err_.z; }

    // The history in one slot (save) and back (restore): follow saves at its start, so
    // a caller stepping several ridges can undo the ones that succeeded.
    void save() noexcept {
        copy(lam_.data(), saved_.lam.data(), n2_); copy(pu_.data(), saved_.u.data(), n2_);
        copy8(state_.data(), saved_.state.data()); copy(sign_.data(), saved_.sign.data());
        saved_.s_prev = s_prev_; saved_.z_prev = z_prev_; saved_.has_z = has_z_;
        saved_.solves = solves_; saved_.events = events_;
        saved_.pristine = pristine_;
        saved_.fr_mu = fr_mu_; saved_.fr_muk = fr_muk_;
    }
    void restore() noexcept {
        copy(saved_.lam.data(), lam_.data(), n2_); copy(saved_.u.data(), pu_.data(), n2_);
        copy(pu_.data(), uy_prev_.data());
        copy8(saved_.state.data(), state_.data()); copy(saved_.sign.data(), sign_.data());
        for (std::size_t i = 0; i < n_; ++i) sliding_[i] = state_[i] == kContactSlip;
        s_prev_ = saved_.s_prev; z_prev_ = saved_.z_prev; has_z_ = saved_.has_z;
        solves_ = saved_.solves; events_ = saved_.events;
        pristine_ = saved_.pristine;
        fr_mu_ = saved_.fr_mu; fr_muk_ = saved_.fr_muk;
        unit_.valid = false;
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
        unit_.valid = false;
        aff_.stage = 0;
        pristine_ = false;
        fr_mu_ = params.mu; fr_muk_ = params.mu_kinetic;
    }

private:
    // ---- path following and load-point solves (contact_path.hpp)
    std::size_t segment_end(const double* ys, const double* zs, std::size_t N, std::size_t k) const noexcept;
    void fill_rows(std::size_t a, std::size_t b, const double* lc, const double* uc, const double* l1,
                   const double* u1, double th, std::size_t L) noexcept;
    int unit_response() noexcept;
    ContactStatus changed(double tiny_y, double tiny_z) noexcept;
    double begin_point_solve(double zp) noexcept;
    void set_scale_len(double zp) noexcept;
    ContactStatus resolve_point(double tiny_y, double tiny_z) noexcept;
    ContactStatus follow_segment(double s1, double z1, std::size_t L, double eps, bool direct,
                                 bool affine) noexcept;
    double first_event(const double* lc, const double* uc, const double* l1, const double* u1, double zc,
                       double z1, double eps, std::size_t& n_ev) noexcept;
    ContactStatus apply_events(std::size_t n_ev, std::size_t& changes) noexcept;
    ContactStatus settle_friction() noexcept;
    ContactStatus cascade(std::size_t& changes) noexcept;
    ContactStatus damped_newton(double plate_z, double ds, double atol, int& it) noexcept;

    void set_path_cones() noexcept {
        for (std::size_t i = 0; i < n_; ++i) act_.mu[i] = state_[i] == kContactSlip ? params.mu_kinetic : params.mu;
    }

    // The status sets met at the current point (a cycle guard, the reference's
    // `seen`): one byte per node (3 state + sign + 1), plain or "resolved" entries.
    void encode_statuses(std::int8_t* key) const noexcept {
        for (std::size_t i = 0; i < n_; ++i)
            key[i] = static_cast<std::int8_t>(3 * state_[i] + (sign_[i] > 0 ? 2 : (sign_[i] < 0 ? 0 : 1)));
    }
    bool seen_has(const std::int8_t* key, bool resolved) const noexcept {
        for (std::size_t q = 0; q < ev_.n_seen; ++q) {
            if (ev_.seen_resolved[q] != resolved) continue;
            if (std::memcmp(ev_.seen.data() + q * n_, key, n_) == 0) return true;
        }
        return false;
    }
    bool seen_add(const std::int8_t* key, bool resolved) noexcept {
        if (ev_.n_seen >= kSeenCap) return false;
        std::memcpy(ev_.seen.data() + ev_.n_seen * n_, key, n_);
        ev_.seen_resolved[ev_.n_seen++] = resolved;
        return true;
    }
    // A status cycle at the current point: the error and where it happened.
    ContactStatus cycle_error() noexcept {
        err_.info = static_cast<long>(ev_.n_seen);
        err_.y = s_prev_; err_.z = z_prev_;
        return ContactStatus::status_cycle;
    }

public:

    // ---- the pieces (public for path-following steppers; defined in contact_piece.hpp,
    // classify and jacobian in contact_path.hpp)

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
                            double ds) noexcept;

    // Alart-Curnier residual F (2n) at (lam, u), the classification open / stick /
    // slip and the slip signs; returns max |F|. Uses the per-node cone of this step.
    double classify(const double* lam, const double* u, double plate_z, double ds, double* F, std::int8_t* state,
                    double* sgn) const noexcept;

    // Prepare the system of the piece (state, sign): reuse the factors when they are
    // of this piece; else, when the piece differs from the factored base piece by at
    // most kMaxBorder unknowns / equations, border the base (update_piece); else
    // factor it afresh (refactor_piece). Returns 0 or the 1-based row of a zero pivot.
    int factor_piece(const std::int8_t* state, const double* sign) noexcept;

    // Factor the piece (state, piece_.slip_coef) as the new base, no border.
    int refactor_piece(const std::int8_t* state) noexcept;

    // Forces of the prepared piece for the plate at plate_z, slip increment ds.
    void solve_prepared(double plate_z, double ds, double* lam) noexcept { solve_prepared(plate_z, ds, lam, false, 0, 0); }

    // unit: the right-hand side is az on every contact equation and ay on every stick
    // equation (the response to a unit plate motion), instead of the plate's gaps.
    void solve_prepared(double plate_z, double ds, double* lam, bool unit, double az, double ay) noexcept;

    // Forces and displacements of the piece (state, sign) for the plate at (plate_y,
    // plate_z). Within one piece the response is affine in the plate position (the
    // stick equations' right-hand side uy_prev + ds = (uy_prev - s_prev) + plate_y
    // keeps uy_prev - s_prev while the nodes stay stuck), so the second time a piece
    // is met its responses to unit plate motions are solved, and from then on a step
    // of the same piece costs O(n): the reference solution plus the plate's moves
    // times the unit responses. Any change of the piece, or of uy_prev - s_prev on its
    // stuck nodes beyond round-off, starts over.
    int piece_response(const std::int8_t* state, const double* sign, double plate_z, double plate_y, double ds,
                       double* lam, double* u) noexcept;

    // x of the prepared piece for right-hand sides b (base equations, overwritten) and
    // c (border rows, overwritten), as forces lam (2n).
    void solve_bordered(double* b, double* c, double* lam, bool base_solved = false) noexcept;

    // The stuck nodes' offsets uy_prev - s_prev are those of the affine reference.
    // Within one piece they are unchanged in exact arithmetic (w = 0 on a stuck node);
    // what changes is the round-off of u_y, about 1e-19 m. The test is relative to the
    // step's length scale (the indent, or the largest tangential displacement): a
    // difference of 1e-13 of it moves the forces by about 1e-13 relative, far below
    // the solver tolerance, while a history that really differs (set_history, a
    // stuck node that slid meanwhile) is caught.
    bool stick_offsets_unchanged() const noexcept;

    int solve_piece(const std::int8_t* state, const double* sign, double plate_z, double ds,
                    double* lam) noexcept;

    // Generalised Jacobian of the Alart-Curnier residual for the classification
    // (state, sign) into J (2n x 2n, row-major).
    void jacobian(const std::int8_t* state, const double* sign, double* J) const noexcept;

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
    // base_.M. A nearby piece P1 is solved as the bordered system
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

    std::size_t eq_row(std::size_t k) const noexcept {  // C row of base equation k
        return base_.kind[k] ? base_.node[k] : n_ + base_.node[k];
    }
    // coefficient of unknown (ln_i with slip coefficient coef, or lt_i) in C row r
    double coef_ln(std::size_t r, std::size_t i, double coef) const noexcept {
        const double* c = C_.data() + r * n2_;
        return c[i] * coef - c[n_ + i];
    }
    double coef_lt(std::size_t r, std::size_t i) const noexcept { return C_[r * n2_ + i]; }
    // coefficient of base unknown k in C row r
    double base_coef(std::size_t r, std::size_t k) const noexcept {
        const std::size_t i = base_.node[k];
        return base_.kind[k] ? coef_lt(r, i) : coef_ln(r, i, base_.coef[i]);
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

    // (defined in contact_piece.hpp)
    void base_changing() noexcept;
    double border_row_dot(std::size_t r, const double* x) const noexcept;
    bool update_piece(const std::int8_t* state) noexcept;
    bool factor_s(std::size_t nb) noexcept;
    bool extend_s(std::size_t nb0, std::size_t nb) noexcept;
    static bool finish_extension(double* A, std::size_t lda, std::size_t m0, std::size_t k, int* piv) noexcept;
    bool extend_base(const std::int8_t* state) noexcept;

    // ---- the model (fixed at construction)
    std::size_t n_, n2_;              // contact nodes; unknowns (lt, ln) and displacements (u_y, u_z)
    std::vector<double> C_, z0_, w_;  // compliance (2n x 2n, row-major); node heights; node weights
    double w_tol_, r_ = 0.0, z0_max_ = 0.0;  // slip increment tolerance; Alart-Curnier stiffness; crown height
    // event tolerances (set_event_tolerances): the cascade's and the cycle rule's zero
    // tests of gaps and forces, and the event search's "decreasing" thresholds
    double g_tol_ = 0.0, f_tol_ = 0.0, evt_g_tol_ = 0.0, evt_f_tol_ = 0.0;

    // ---- the committed history (what follow leaves and restore brings back)
    std::vector<double> lam_, uy_prev_, sign_;  // forces (lt, ln); u_y at the last load; slip signs
    std::vector<std::int8_t> state_;            // node statuses (open / stick / slip)
    std::vector<std::uint8_t> sliding_;         // state_ == slip, as the reference's flags
    std::vector<double> pu_;                    // displacements (u_y, u_z) of the state
    double s_prev_ = 0.0, z_prev_ = 0.0;        // plate position (y) and height (z) of the state
    bool has_z_ = false, pristine_ = true;      // placed; no history since construction / reset
    double fr_mu_ = 0.0, fr_muk_ = 0.0;         // friction the state was solved with (settle_friction)
    long solves_ = 0, events_ = 0;              // solves and events of the path following since reset
    double scale_len_ = 1e-9;  // the length scale of the current step (m), see stick_offsets_unchanged

    // The history as follow found it (save / restore): a failed call puts it back.
    struct Snapshot {
        std::vector<double> lam, u, sign;  // lam_, pu_, sign_
        std::vector<std::int8_t> state;    // state_
        double s_prev = 0.0, z_prev = 0.0, fr_mu = 0.0, fr_muk = 0.0;
        bool has_z = false, pristine = true;
        long solves = 0, events = 0;
        void allocate(std::size_t n) {
            lam.assign(2 * n, 0.0); u.assign(2 * n, 0.0); sign.assign(n, 0.0);
            state.assign(n, kContactOpen);
        }
    };
    Snapshot saved_;

    // The results of the last step() (forces(), displacement(), reported_state(), ...).
    struct StepResult {
        std::vector<double> lam, u, forces;  // forces (lt, ln); displacements; f = (lt, -ln)
        std::vector<std::int8_t> state;      // the reported statuses
        double slip_fraction = 0.0;
        int iterations = 0;                  // solves the step took
        void allocate(std::size_t n) {
            lam.assign(2 * n, 0.0); u.assign(2 * n, 0.0); forces.assign(2 * n, 0.0);
            state.assign(n, kContactOpen);
        }
    };
    StepResult stepped_;

    // The solution of solve_load at one load point, before the caller accepts it.
    struct LoadSolution {
        std::vector<double> lam, u, sign;  // forces, displacements, slip signs
        std::vector<std::int8_t> state;    // its classification
        void allocate(std::size_t n) {
            lam.assign(2 * n, 0.0); u.assign(2 * n, 0.0); sign.assign(n, 0.0);
            state.assign(n, kContactOpen);
        }
    };
    LoadSolution solved_;

    // The active-set iteration of a load point (solve_load, resolve_point, cascade).
    struct ActiveSet {
        std::vector<double> mu;                             // each node's cone this step (static / kinetic)
        std::vector<std::int8_t> state, next_state;         // the classification and the next one
        std::vector<double> sign, next_sign;                // their slip signs
        std::vector<double> F;                              // Alart-Curnier residual (2n)
        std::vector<std::int8_t> prev_state;                // the accepted statuses at the point's start
        std::vector<double> prev_sign;                      // and their signs
        std::vector<double> first_lam, first_u, first_sign; // solve_load(exact): the first answer within tolerance
        std::vector<std::int8_t> first_state;
        void allocate(std::size_t n) {
            mu.assign(n, 0.0); F.assign(2 * n, 0.0);
            state.assign(n, kContactOpen); next_state.assign(n, kContactOpen);
            sign.assign(n, 0.0); next_sign.assign(n, 0.0);
            prev_state.assign(n, kContactOpen); prev_sign.assign(n, 0.0);
            first_lam.assign(2 * n, 0.0); first_u.assign(2 * n, 0.0); first_sign.assign(n, 0.0);
            first_state.assign(n, kContactOpen);
        }
    };
    ActiveSet act_;

    // The damped Newton fallback (damped_newton).
    struct Newton {
        std::vector<double> J;        // generalised Jacobian (2n x 2n), then its LU
        std::vector<int> piv;         // its pivots
        std::vector<double> step;     // Newton direction
        std::vector<double> lam, u, F;  // trial point of the line search and its residual
        void allocate(std::size_t n) {
            J.assign(4 * n * n, 0.0); piv.assign(2 * n, 0); step.assign(2 * n, 0.0);
            lam.assign(2 * n, 0.0); u.assign(2 * n, 0.0); F.assign(2 * n, 0.0);
        }
    };
    Newton newton_;

    // The prepared piece (factor_piece): its statuses and slip coefficients mu s.
    struct PieceKey {
        std::vector<std::int8_t> state;  // statuses of the prepared piece
        std::vector<double> coef;        // its slip coefficients
        std::vector<double> slip_coef;   // those of the piece being prepared
        long id = 0;                     // changes whenever the prepared piece does
        void allocate(std::size_t n) {
            state.assign(n, kContactOpen); coef.assign(n, 0.0); slip_coef.assign(n, 0.0);
        }
    };
    PieceKey piece_;

    // The factored base piece. Position k of its unknowns / equations is ln (kind 0, with
    // equation g) or lt (kind 1, with equation w) of node node[k]; m of them.
    struct BaseFactors {
        std::vector<double> M;              // LU factors (ld 2n)
        std::vector<int> piv;               // their pivots
        std::vector<std::size_t> node;      // node of each position
        std::vector<std::uint8_t> kind;     // kind of each position
        std::size_t m = 0;
        std::vector<long> pos_ln, pos_lt;   // per node: the position of its ln / lt (-1: none)
        std::vector<std::int8_t> state;     // the base piece's statuses
        std::vector<double> coef;           // and slip coefficients
        bool valid = false;                 // M holds factors
        std::vector<double> rhs;            // the base right-hand side of a solve (solve_prepared)
        std::vector<double> unit_z;         // base solves of the unit right-hand sides (az, ay) = (1, 0), (0, 1)
        bool unit_valid[2] = {false, false};
        std::vector<double> load_rhs, load_z;  // the last base solve of a load's right-hand side (solve_bordered)
        bool load_valid = false;
        void allocate(std::size_t n) {
            const std::size_t n2 = 2 * n;
            M.assign(n2 * n2, 0.0); piv.assign(n2, 0); node.assign(n2, 0); kind.assign(n2, 0);
            pos_ln.assign(n, -1); pos_lt.assign(n, -1); state.assign(n, kContactOpen); coef.assign(n, 0.0);
            rhs.assign(n2, 0.0); unit_z.assign(2 * n2, 0.0); load_rhs.assign(n2, 0.0); load_z.assign(n2, 0.0);
        }
    };
    BaseFactors base_;

    // The border of the prepared piece over the base (update_piece), and the last one's,
    // whose rows, columns and Schur complement entries the next border keeps.
    struct Border {
        std::vector<BorderRow> rows;        // its rows and columns, n of each
        std::vector<BorderCol> cols;
        std::size_t n = 0;
        std::vector<double> Wt;             // W^T rows over the base unknowns (ld 2n)
        std::vector<double> S;              // Schur complement before factoring (ld kMaxBorder)
        std::vector<double> S_lu;           // its LU factors
        std::vector<int> piv;               // their pivots
        bool lu_ok = false;                 // S_lu holds the factors of the last border's S (extend_s extends them)
        std::vector<double> Wt_spare, S_spare;  // rebuild buffers (swapped with Wt, S)
        std::vector<double> rhs;            // right-hand side of the border rows, then their unknowns
        std::vector<std::size_t> vslot;     // M0^-1 V: column c of the border is slot vslot[c] of the column cache
        std::vector<const double*> vcol;    // its address (set where it is used)
        std::vector<double> vnew;           // new columns to solve / extend (kMaxBorder x 2n)
        std::vector<std::size_t> new_col;   // the border column of each of them
        std::vector<BorderRow> last_rows;   // the last border's rows and columns, their coefficients, count
        std::vector<BorderCol> last_cols;
        std::vector<double> last_row_coef, last_col_coef;
        std::size_t last_n = 0;
        std::vector<long> row_map, col_map; // per row / column: its place in the last border (-1: new)
        std::vector<BorderRow> tmp_rows;    // reordering scratch
        std::vector<BorderCol> tmp_cols;
        std::vector<long> node_head;        // per node: the first entry of its chain (-1 between uses)
        std::vector<long> chain_next;       // the chains of the last border's entries
        void allocate(std::size_t n_nodes) {
            const std::size_t n2 = 2 * n_nodes, K = kMaxBorder;
            rows.resize(K); cols.resize(K);
            Wt.assign(K * n2, 0.0); S.assign(K * K, 0.0); S_lu.assign(K * K, 0.0); piv.assign(K, 0);
            Wt_spare.assign(K * n2, 0.0); S_spare.assign(K * K, 0.0); rhs.assign(K, 0.0);
            vslot.assign(K, 0); vcol.assign(K, nullptr); vnew.assign(K * n2, 0.0); new_col.assign(K, 0);
            last_rows.resize(K); last_cols.resize(K); last_row_coef.assign(K, 0.0); last_col_coef.assign(K, 0.0);
            row_map.assign(K, -1); col_map.assign(K, -1); tmp_rows.resize(K); tmp_cols.resize(K);
            node_head.assign(n_nodes, -1); chain_next.assign(K, -1);
        }
    };
    Border border_;

    // Solved border columns M0^-1 V of the current base, kept for the next borders.
    struct ColumnCache {
        std::vector<double> data;          // kColCache columns (ld 2n)
        std::vector<CachedCol> key;        // what each slot holds
        std::size_t n = 0, next_slot = 0;  // slots in use; the next slot to replace
        std::vector<std::uint8_t> used;    // slots the current border reads
        std::vector<long> chain_next;      // per-node chains over the slots
        void allocate(std::size_t n_nodes) {
            data.assign(kColCache * 2 * n_nodes, 0.0); key.resize(kColCache);
            used.assign(kColCache, 0); chain_next.assign(kColCache, -1);
        }
    };
    ColumnCache cols_;

    // The affine response of the current piece (piece_response): the reference solution
    // at (plate_z, plate_y) and the responses to unit plate motions.
    struct AffineResponse {
        std::vector<double> lam, u;          // the reference solution
        std::vector<double> lam_dz, u_dz;    // response to a unit rise of the plate
        std::vector<double> lam_dy, u_dy;    // response to a unit plate motion along y
        std::vector<double> stick_offset;    // uy_prev - s_prev of the reference
        double plate_z = 0.0, plate_y = 0.0;
        long piece = -1;                     // piece_.id it holds for
        int stage = 0;                       // 0 none, 1 reference only, 2 with the unit responses
        void allocate(std::size_t n) {
            for (auto* v : {&lam, &u, &lam_dz, &u_dz, &lam_dy, &u_dy}) v->assign(2 * n, 0.0);
            stick_offset.assign(n, 0.0);
        }
    };
    AffineResponse aff_;

    // The unit responses of the current statuses (unit_response) and their key.
    struct UnitResponse {
        std::vector<double> lam_dy, u_dy;  // response to a unit plate displacement along y
        std::vector<double> lam_dz, u_dz;  // response to a unit rise of the plate
        std::vector<std::int8_t> state;    // the statuses, signs and friction they hold for
        std::vector<double> sign;
        double mu = 0.0, mu_kinetic = 0.0;
        bool valid = false;
        void allocate(std::size_t n) {
            for (auto* v : {&lam_dy, &u_dy, &lam_dz, &u_dz}) v->assign(2 * n, 0.0);
            state.assign(n, kContactOpen); sign.assign(n, 0.0);
        }
    };
    UnitResponse unit_;

    // Scratch of the path following: the end of the current piece, the events found
    // there and the status sets met at the current point.
    static constexpr std::size_t kSeenCap = 256;  // status sets kept per point (more: status_cycle)
    struct EventScratch {
        std::vector<double> lam_end, u_end;  // the piece's solution at the segment's end
        std::vector<double> frac;            // crossing of each kind and node (kind-major, 4n)
        std::vector<std::int8_t> kind;       // the events at the first crossing: kind and node
        std::vector<std::size_t> node;
        std::vector<std::int8_t> seen, key;  // status sets met at the point (kSeenCap x n); one set's key
        std::vector<bool> seen_resolved;     // per set: a "resolved" entry
        std::size_t n_seen = 0;
        void allocate(std::size_t n) {
            lam_end.assign(2 * n, 0.0); u_end.assign(2 * n, 0.0); frac.assign(4 * n, 0.0);
            kind.assign(4 * n, 0); node.assign(4 * n, 0);
            seen.assign(kSeenCap * n, 0); key.assign(n, 0); seen_resolved.assign(kSeenCap, false);
        }
    };
    EventScratch ev_;

    // Where follow writes its samples, and the projected outputs (set_projection).
    struct Outputs {
        double* lam = nullptr;           // row k at lam + (row0 + k) * stride2, likewise u
        double* u = nullptr;
        std::int8_t* state = nullptr;    // row k at state + (row0 + k) * stride1
        std::size_t stride2 = 0, stride1 = 0, row0 = 0;
        Extra extra;                     // projections, slip fraction, flags (follow with Extra)
        std::size_t q = 0;               // projection rows
        std::vector<double> Pt;          // the projection, column-major (q x 2n)
        std::vector<double> pc, pd;      // P lam at the piece's start and its change
    };
    Outputs out_;

    // P lam and the rows piece_displacement computes.
    struct DisplacementScratch {
        std::vector<double> plam;
        std::vector<std::size_t> free_rows;
        void allocate(std::size_t n) { plam.assign(2 * n, 0.0); free_rows.assign(2 * n, 0); }
    };
    DisplacementScratch disp_;

    // Counters since construction (factorizations(), updates(), ...).
    struct Counters {
        long factorizations = 0, updates = 0, extensions = 0, border_extensions = 0, affine = 0, rhs_reuses = 0;
    };
    Counters stats_;

    // Details of the last failure (error_info(), error_residual(), ...).
    struct ErrorDetail {
        long info = 0;
        double residual = 0.0, atol = 0.0;  // Newton's residual and tolerance (no_convergence)
        double y = 0.0, z = 0.0;            // the load point of a path-following failure
    };
    ErrorDetail err_;
};

}  // namespace tactile
