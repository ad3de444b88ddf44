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
        const ContactStatus s = follow(&plate_y, &plate_z, 1, every, stepped_.lam.data(), stepped_.u.data(), stepped_.state.data(),
                                       0, 0);
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
                             int& it, bool exact = false) noexcept {
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
        classify(solved_.lam.data(), solved_.u.data(), plate_z, ds, act_.F.data(), solved_.state.data(), solved_.sign.data());
        return ContactStatus::ok;
    }

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
                         std::size_t out_stride1) noexcept {
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
        saved_.s_prev = s_prev_; saved_.z_prev = z_prev_; saved_.has_z = has_z_; saved_.solves = solves_; saved_.events = events_;
        saved_.pristine = pristine_;
        saved_.fr_mu = fr_mu_; saved_.fr_muk = fr_muk_;
    }
    void restore() noexcept {
        copy(saved_.lam.data(), lam_.data(), n2_); copy(saved_.u.data(), pu_.data(), n2_);
        copy(pu_.data(), uy_prev_.data());
        copy8(saved_.state.data(), state_.data()); copy(saved_.sign.data(), sign_.data());
        for (std::size_t i = 0; i < n_; ++i) sliding_[i] = state_[i] == kContactSlip;
        s_prev_ = saved_.s_prev; z_prev_ = saved_.z_prev; has_z_ = saved_.has_z; solves_ = saved_.solves; events_ = saved_.events;
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

    void set_path_cones() noexcept {
        for (std::size_t i = 0; i < n_; ++i) act_.mu[i] = state_[i] == kContactSlip ? params.mu_kinetic : params.mu;
    }

    // Responses (rs, us) to a unit plate displacement along y and (rz, uz) to a unit
    // rise of the plate for the current statuses, kept while they and mu do not change.
    int unit_response() noexcept {
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

    // A status change at the current point (the reference's _changed): counted; if
    // the statuses return to a set already met at this point, all of them are decided
    // together by resolve_point; a second return is a cycle (status_cycle).
    ContactStatus changed(double tiny_y, double tiny_z) noexcept {
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

    ContactStatus cycle_error() noexcept {
        err_.info = static_cast<long>(ev_.n_seen);
        err_.y = s_prev_; err_.z = z_prev_;
        return ContactStatus::status_cycle;
    }

    // The start of a solve at the current point with the plate face at zp: statuses and
    // signs back to the accepted ones, the path's cones, the length scale of the
    // tolerance, and the working classification copied from the accepted one. Returns
    // the absolute tolerance of the Alart-Curnier residual.
    double begin_point_solve(double zp) noexcept {
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
    ContactStatus follow_segment(double s1, double z1, std::size_t L, double eps, bool direct,
                                 bool affine) noexcept {
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
    double first_event(const double* lc, const double* uc, const double* l1, const double* u1, double zc, double z1,
                       double eps, std::size_t& n_ev) noexcept {
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

    ContactStatus apply_events(std::size_t n_ev, std::size_t& changes) noexcept {
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
    ContactStatus settle_friction() noexcept {
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
    ContactStatus cascade(std::size_t& changes) noexcept {
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

    // Prepare the system of the piece (state, sign): reuse the factors when they are
    // of this piece; else, when the piece differs from the factored base piece by at
    // most kMaxBorder unknowns / equations, border the base (update_piece); else
    // factor it afresh (refactor_piece). Returns 0 or the 1-based row of a zero pivot.
    int factor_piece(const std::int8_t* state, const double* sign) noexcept {
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

    // Factor the piece (state, piece_.slip_coef) as the new base, no border.
    int refactor_piece(const std::int8_t* state) noexcept {
        const std::size_t n = n_;
        ++piece_.id;
        base_changing();
        std::size_t m = 0;
        for (std::size_t i = 0; i < n; ++i) base_.pos_ln[i] = base_.pos_lt[i] = -1;
        for (std::size_t i = 0; i < n; ++i)
            if (state[i] != kContactOpen) { base_.node[m] = i; base_.kind[m] = 0; base_.pos_ln[i] = static_cast<long>(m++); }
        for (std::size_t i = 0; i < n; ++i)
            if (state[i] == kContactStick) { base_.node[m] = i; base_.kind[m] = 1; base_.pos_lt[i] = static_cast<long>(m++); }
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

    // Forces of the prepared piece for the plate at plate_z, slip increment ds.
    void solve_prepared(double plate_z, double ds, double* lam) noexcept { solve_prepared(plate_z, ds, lam, false, 0, 0); }

    // unit: the right-hand side is az on every contact equation and ay on every stick
    // equation (the response to a unit plate motion), instead of the plate's gaps.
    void solve_prepared(double plate_z, double ds, double* lam, bool unit, double az, double ay) noexcept {
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

    // x of the prepared piece for right-hand sides b (base equations, overwritten) and
    // c (border rows, overwritten), as forces lam (2n).
    void solve_bordered(double* b, double* c, double* lam, bool base_solved = false) noexcept {
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
            if (piece_.state[i] != kContactStick) continue;
            const double v = uy_prev_[i] - s_prev_, ref = aff_.stick_offset[i];
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

    // The base factors are about to change (refactor_piece, extend_base): they are not valid
    // until the change succeeds, and the border and every solve kept with the old base (the
    // M0^-1 V columns, the unit and load right-hand sides' base solves) are forgotten.
    void base_changing() noexcept {
        base_.valid = false;
        border_.n = 0;
        cols_.n = 0;
        border_.last_n = 0;
        border_.lu_ok = false;
        base_.unit_valid[0] = base_.unit_valid[1] = false;
        base_.load_valid = false;
    }

    std::size_t eq_row(std::size_t k) const noexcept {  // C row of base equation k
        return base_.kind[k] ? base_.node[k] : n_ + base_.node[k];
    }
    // Border row r of W^T (border_.Wt) against x (length base_.m). The rows of the force laws are
    // zero but at one entry (kFix: the unknown fixed to zero) or two (kSlipRow: lt_i and
    // ln_i), so they cost those entries, not a dot product over the base: with the
    // slip front moving, most border rows are of this kind, and the dot products were
    // a bordered solve's largest cost after its base solve.
    double border_row_dot(std::size_t r, const double* x) const noexcept {
        const BorderRow& br = border_.rows[r];
        const double* w = border_.Wt.data() + r * n2_;
        if (br.kind == kFix) return w[br.pos] * x[br.pos];
        if (br.kind == kSlipRow) {
            const std::size_t q = static_cast<std::size_t>(base_.pos_ln[br.node]);
            return w[br.pos] * x[br.pos] + w[q] * x[q];
        }
        return dot(w, x, base_.m);
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

    // Border the base for the piece (state, piece_.slip_coef); false if it needs more than
    // kMaxBorder borders or its Schur complement is singular (then refactor).
    bool update_piece(const std::int8_t* state) noexcept {
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
        for (std::size_t r = 0; r < nb; ++r) border_.row_map[r] = kept(border_.rows[r], row_coef(border_.rows[r]), border_.last_rows, border_.last_row_coef);
        unlink_chains(border_.last_rows.data(), border_.last_n, head);
        link_chains(border_.last_cols.data(), border_.last_n, head, border_.chain_next.data());
        for (std::size_t c = 0; c < nb; ++c) border_.col_map[c] = kept(border_.cols[c], col_coef(border_.cols[c]), border_.last_cols, border_.last_col_coef);
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
        const bool extend = border_.lu_ok && border_.last_n > 0 && kept_r == border_.last_n && kept_c == border_.last_n;  // (so nb >= border_.last_n)
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
            const double* orow = border_.row_map[r] >= 0 ? border_.S.data() + static_cast<std::size_t>(border_.row_map[r]) * K : nullptr;
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
    bool factor_s(std::size_t nb) noexcept {
        const std::size_t K = kMaxBorder;
        for (std::size_t r = 0; r < nb; ++r) copy(border_.S.data() + r * K, border_.S_lu.data() + r * K, nb);
        return nb == 0 || lu_factor(border_.S_lu.data(), nb, K, border_.piv.data()) == 0;
    }

    // border_.S_lu holds the factors of border_.S's leading nb0 x nb0 block (the last border's S):
    // extend them to all of border_.S (nb square), as extend_base extends the base: with
    // P0 S00 = L0 U0, the new columns through P0 and L0 (Y), the new rows through U0
    // (X), and the LU of Z - X Y with partial pivoting within the new block.
    bool extend_s(std::size_t nb0, std::size_t nb) noexcept {
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
    bool extend_base(const std::int8_t* state) noexcept {
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
            if (state[i] == kContactStick) { base_.node[q] = i; base_.kind[q] = 1; base_.pos_lt[i] = static_cast<long>(q++); }
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

    // The damped semismooth Newton method on F from the committed forces, result in
    // solved_.lam / solved_.u (the classification is redone by the caller).
    ContactStatus damped_newton(double plate_z, double ds, double atol, int& it) noexcept {
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
        bool lu_ok = false;                 // S_lu holds the factors of the last border's S (extend_s may extend them)
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
