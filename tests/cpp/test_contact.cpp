// Stand-alone test of contact_solver.hpp (ContactSolverKernel) against references made
// by the compiled module (see tests/test_cpp_kernels.py), built with AddressSanitizer
// and UBSan.
//
// Input file (native endianness): u64 n, N, max_iter, max_active_set_iter; f64 r,
// w_tol, mu, mu_kinetic, tol, g_tol, f_tol, evt_g_tol, evt_f_tol (what
// ContactSolver gives _core._ContactSolver, set_params and set_event_tolerances);
// f64 compliance[2n*2n], node_z[n], weights[n], plate_y[N], plate_z[N]; then three
// runs of the module, each from a new solver: follow(every=true), follow(every=false)
// and step(every=false) sample by sample, each as f64 lam[N*2n] (lt, ln), i8
// state[N*n], i64 solves, events, factorizations, updates.
//
// For both steppings: follow over the whole path in one call (also as a pad's
// projected follow reads it, and on the baseline kernels) and step sample by sample
// against the references (forces within 1e-8 of the peak: -O1 rounds differently
// from the -O2 module; statuses and counters identical); a non-finite plate position
// rejected with the history unchanged; a kernel without iterations (max_iter =
// max_active_set_iter = 0) failing at every breakaway cascade with the history
// unchanged, then stepping on with the normal parameters; restore() undoing a
// stretch that held the gross-slip cascade.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "contact_solver.hpp"
#include "check.hpp"

using tactile::ContactSolverKernel;
using tactile::ContactStatus;

struct Ref {
    std::vector<double> lam;       // (N, 2n) (lt, ln)
    std::vector<std::int8_t> state;  // (N, n)
    long solves, events, factorizations, updates;
    double peak;
};

struct Setup {
    std::size_t n, N;
    int max_iter, max_as;
    double r, w_tol, mu, mu_k, tol, g_tol, f_tol, evt_g_tol, evt_f_tol;
    std::vector<double> C, z0, w, y, z;

    ContactSolverKernel make() const {
        ContactSolverKernel k(n, C.data(), z0.data(), w.data(), r, w_tol);
        k.params = {mu, mu_k, tol, max_iter, max_as};
        k.set_event_tolerances(g_tol, f_tol, evt_g_tol, evt_f_tol);
        return k;
    }
    void normal(ContactSolverKernel& k) const { k.params = {mu, mu_k, tol, max_iter, max_as}; }
    // no active-set step and no Newton step: any solve that needs one (a breakaway
    // cascade, a point resolution) fails
    void crippled(ContactSolverKernel& k) const { k.params = {mu, mu_k, tol, 0, 0}; }
};

// Everything the kernel keeps of the path followed so far.
struct History {
    std::vector<double> lam, uy, sign, pu;
    std::vector<std::int8_t> state;
    std::vector<std::uint8_t> sliding;
    double s_prev, z_prev;
    bool placed, pristine;
    long solves, events;
};

static History history(const ContactSolverKernel& k) {
    const std::size_t n = k.n_nodes();
    History h;
    h.lam.assign(k.lam(), k.lam() + 2 * n);
    h.uy.assign(k.uy_prev(), k.uy_prev() + n);
    h.sign.assign(k.sign(), k.sign() + n);
    h.pu.assign(k.path_displacement(), k.path_displacement() + 2 * n);
    h.state.assign(k.state(), k.state() + n);
    h.sliding.assign(k.sliding(), k.sliding() + n);
    h.s_prev = k.s_prev();
    h.z_prev = k.z_prev();
    h.placed = k.placed();
    h.pristine = k.pristine();
    h.solves = k.solves();
    h.events = k.events();
    return h;
}

template <typename T>
static bool bits_equal(const std::vector<T>& a, const std::vector<T>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

static bool same_history(const History& a, const History& b) {
    return bits_equal(a.lam, b.lam) && bits_equal(a.uy, b.uy) && bits_equal(a.sign, b.sign) &&
           bits_equal(a.pu, b.pu) && bits_equal(a.state, b.state) && bits_equal(a.sliding, b.sliding) &&
           std::memcmp(&a.s_prev, &b.s_prev, sizeof(double)) == 0 &&
           std::memcmp(&a.z_prev, &b.z_prev, sizeof(double)) == 0 && a.placed == b.placed &&
           a.pristine == b.pristine && a.solves == b.solves && a.events == b.events;
}

// Rows [a, b) of forces lam (lt, ln) against the reference: the largest deviation
// (returned) and the number of samples whose statuses differ (added to *mismatch).
static double compare_rows(const Setup& S, const Ref& ref, const double* lam, const std::int8_t* state, std::size_t a,
                           std::size_t b, long* mismatch) {
    const std::size_t n = S.n, n2 = 2 * n;
    double dev = 0.0;
    for (std::size_t t = a; t < b; ++t) {
        for (std::size_t i = 0; i < n2; ++i) {
            const double d = std::fabs(lam[(t - a) * n2 + i] - ref.lam[t * n2 + i]);
            if (!(d <= dev)) dev = d;  // a NaN sticks
        }
        if (state && std::memcmp(state + (t - a) * n, ref.state.data() + t * n, n) != 0) ++*mismatch;
    }
    return dev;
}

// The slip fraction report() gives for the statuses st.
static double slip_fraction(const Setup& S, const std::int8_t* st) {
    double total = 0.0, slipping = 0.0;
    for (std::size_t i = 0; i < S.n; ++i) {
        if (st[i] != tactile::kContactOpen) total += S.w[i];
        if (st[i] == tactile::kContactSlip) slipping += S.w[i];
    }
    return total > 0 ? slipping / total : 0.0;
}

// Forces agree with the module's within kRtol of their peak (measured: 3e-13); the
// statuses of every sample are the same (no round-off tie on this path).
constexpr double kRtol = 1e-8;

// One sample by step(): forces (lt, ln) and statuses into row t of lam / state.
static ContactStatus step_into(const Setup& S, ContactSolverKernel& k, std::size_t t, bool every, double* lam,
                               std::int8_t* state) {
    const ContactStatus st = k.step(S.y[t], S.z[t], every);
    if (st != ContactStatus::ok) return st;
    const std::size_t n = S.n;
    const double* f = k.forces();
    for (std::size_t i = 0; i < n; ++i) {
        lam[i] = f[i];
        lam[n + i] = -f[n + i];
    }
    std::memcpy(state, k.reported_state(), n);
    return st;
}

// Follow the whole path in one call; returns the forces.
static std::vector<double> run_follow(const Setup& S, const Ref& ref, bool every, const char* what) {
    const std::size_t n = S.n, N = S.N, n2 = 2 * n;
    ContactSolverKernel k = S.make();
    std::vector<double> lam(N * n2, NAN), u(N * n2, NAN);
    std::vector<std::int8_t> state(N * n, -1);
    const ContactStatus st = k.follow(S.y.data(), S.z.data(), N, every, lam.data(), u.data(), state.data(), n2, n);
    CHECK(st == ContactStatus::ok, "%s: follow status %d", what, static_cast<int>(st));
    long mismatch = 0;
    const double dev = compare_rows(S, ref, lam.data(), state.data(), 0, N, &mismatch);
    CHECK(dev <= kRtol * ref.peak, "%s: forces deviate by %.3g (%.3g of the peak)", what, dev, dev / ref.peak);
    CHECK(mismatch == 0, "%s: statuses differ at %ld samples", what, mismatch);
    // the displacements are C P lam to the round-off of the piece solves
    std::vector<double> cu(n2);
    double udev = 0.0, upeak = 0.0;
    for (std::size_t t = 0; t < N; ++t) {
        k.displacement(lam.data() + t * n2, cu.data());
        for (std::size_t i = 0; i < n2; ++i) {
            const double d = std::fabs(cu[i] - u[t * n2 + i]);
            if (!(d <= udev)) udev = d;
            upeak = std::fmax(upeak, std::fabs(cu[i]));
        }
    }
    CHECK(udev <= kRtol * upeak, "%s: displacements deviate from C P lam by %.3g of their peak", what, udev / upeak);
    CHECK(k.solves() == ref.solves && k.events() == ref.events, "%s: %ld solves, %ld events; module %ld, %ld", what,
          k.solves(), k.events(), ref.solves, ref.events);
    CHECK(k.factorizations() == ref.factorizations && k.updates() == ref.updates,
          "%s: %ld factorizations, %ld bordered updates; module %ld, %ld", what, k.factorizations(), k.updates(),
          ref.factorizations, ref.updates);
    CHECK(k.updates() > 0, "%s: no bordered update", what);
    CHECK(k.border_extensions() > 0, "%s: no bordered update extended the last border in place", what);
    std::printf("%s: max |lam - module| %.3g N/m (%.3g of the peak %.4g), status mismatches %ld; solves %ld, events %ld, "
                "factorizations %ld, bordered updates %ld (%ld extending the last border), extensions %ld, affine steps "
                "%ld, rhs reuses %ld\n",
                what, dev, dev / ref.peak, ref.peak, mismatch, k.solves(), k.events(), k.factorizations(), k.updates(),
                k.border_extensions(), k.extensions(), k.affine_steps(), k.rhs_reuses());
    return lam;
}

// Step sample by sample; returns the forces.
static std::vector<double> run_step(const Setup& S, const Ref& ref, bool every, const char* what) {
    const std::size_t n = S.n, N = S.N, n2 = 2 * n;
    ContactSolverKernel k = S.make();
    std::vector<double> lam(N * n2, NAN);
    std::vector<std::int8_t> state(N * n, -1);
    long its = 0, bad = 0;
    for (std::size_t t = 0; t < N; ++t) {
        const ContactStatus st = step_into(S, k, t, every, lam.data() + t * n2, state.data() + t * n);
        if (st != ContactStatus::ok) {
            CHECK(false, "%s: step %zu status %d", what, t, static_cast<int>(st));
            return lam;
        }
        its += k.iterations();
        bad += k.slip_fraction() != slip_fraction(S, state.data() + t * n);
    }
    CHECK(bad == 0, "%s: slip fraction differs from the statuses' at %ld samples", what, bad);
    CHECK(its == k.solves(), "%s: iterations %ld, solves %ld", what, its, k.solves());
    long mismatch = 0;
    const double dev = compare_rows(S, ref, lam.data(), state.data(), 0, N, &mismatch);
    CHECK(dev <= kRtol * ref.peak, "%s: forces deviate by %.3g (%.3g of the peak)", what, dev, dev / ref.peak);
    CHECK(mismatch == 0, "%s: statuses differ at %ld samples", what, mismatch);
    CHECK(k.solves() == ref.solves && k.events() == ref.events, "%s: %ld solves, %ld events; module %ld, %ld", what,
          k.solves(), k.events(), ref.solves, ref.events);
    CHECK(k.factorizations() == ref.factorizations && k.updates() == ref.updates,
          "%s: %ld factorizations, %ld bordered updates; module %ld, %ld", what, k.factorizations(), k.updates(),
          ref.factorizations, ref.updates);
    std::printf("%s: max |lam - module| %.3g N/m (%.3g of the peak), status mismatches %ld; solves %ld, events %ld, "
                "factorizations %ld, bordered updates %ld\n",
                what, dev, dev / ref.peak, mismatch, k.solves(), k.events(), k.factorizations(), k.updates());
    return lam;
}

// The path in one call as a pad's projected follow reads it (set_projection, Extra):
// q = 3 functionals of the forces (the sums of lt and of ln, and a weighting of all
// entries) filled along the pieces, the slip fraction and the flags, against the
// rows of run (forces) and the reference's statuses.
static void check_projected(const Setup& S, const Ref& ref, bool every, const std::vector<double>& run,
                            const char* what) {
    const std::size_t n = S.n, N = S.N, n2 = 2 * n, q = 3;
    std::vector<double> P(q * n2, 0.0);
    for (std::size_t j = 0; j < n2; ++j) {
        P[0 * n2 + j] = j < n ? 1.0 : 0.0;
        P[1 * n2 + j] = j < n ? 0.0 : 1.0;
        P[2 * n2 + j] = std::sin(0.7 * static_cast<double>(j + 1));
    }
    ContactSolverKernel k = S.make();
    k.set_projection(P.data(), q);
    CHECK(k.projection_size() == q, "%s: projection size %zu", what, k.projection_size());
    std::vector<double> proj(N * q, NAN), frac(N, NAN);
    std::vector<std::int8_t> flags(N, -1);
    ContactSolverKernel::Extra ex;
    ex.proj = proj.data();
    ex.stride_q = q;
    ex.frac = frac.data();
    ex.flags = flags.data();
    ex.stride_f = 1;
    const ContactStatus st = k.follow(S.y.data(), S.z.data(), N, every, nullptr, nullptr, nullptr, 0, 0, ex);
    CHECK(st == ContactStatus::ok, "%s: status %d", what, static_cast<int>(st));
    double dev = 0.0, peak = 0.0;
    long bad_frac = 0, bad_flags = 0;
    for (std::size_t t = 0; t < N; ++t) {
        for (std::size_t a = 0; a < q; ++a) {
            double want = 0.0;
            for (std::size_t j = 0; j < n2; ++j) want += P[a * n2 + j] * run[t * n2 + j];
            const double d = std::fabs(proj[t * q + a] - want);
            if (!(d <= dev)) dev = d;
            peak = std::fmax(peak, std::fabs(want));
        }
        const std::int8_t* sr = ref.state.data() + t * n;
        bad_frac += std::fabs(frac[t] - slip_fraction(S, sr)) > 1e-15;
        bool touch = false, stick = false;
        for (std::size_t i = 0; i < n; ++i) {
            touch |= sr[i] != tactile::kContactOpen;
            stick |= sr[i] == tactile::kContactStick;
        }
        bad_flags += flags[t] != ((touch ? 1 : 0) | (touch && !stick ? 2 : 0));
    }
    CHECK(dev <= kRtol * peak, "%s: P lam deviates by %.3g of its peak", what, dev / peak);
    CHECK(bad_frac == 0 && bad_flags == 0, "%s: slip fraction wrong at %ld samples, flags at %ld", what, bad_frac,
          bad_flags);
    CHECK(k.solves() == ref.solves && k.events() == ref.events, "%s: %ld solves, %ld events; module %ld, %ld", what,
          k.solves(), k.events(), ref.solves, ref.events);
}

// The path followed in two calls, [0, m) and [m, N) (with every = false the segments
// of equal load increments, and so the round-off, depend on where a call starts).
static std::vector<double> run_split(const Setup& S, bool every, std::size_t m) {
    const std::size_t n = S.n, N = S.N, n2 = 2 * n;
    ContactSolverKernel k = S.make();
    std::vector<double> lam(N * n2, NAN);
    CHECK(k.follow(S.y.data(), S.z.data(), m, every, lam.data(), nullptr, nullptr, n2, n) == ContactStatus::ok &&
              k.follow(S.y.data() + m, S.z.data() + m, N - m, every, lam.data() + m * n2, nullptr, nullptr, n2, n) ==
                  ContactStatus::ok,
          "follow split at %zu failed", m);
    return lam;
}

// A non-finite plate position, in follow and in step, in the middle of the path:
// rejected with non_finite_position, nothing written, the history unchanged; the
// path then goes on exactly (bit for bit) as without the rejected calls.
static void check_non_finite(const Setup& S, bool every, const char* what) {
    const std::size_t n = S.n, N = S.N, n2 = 2 * n, m = N / 2;
    const std::vector<double> run = run_split(S, every, m);
    ContactSolverKernel k = S.make();
    std::vector<double> lam(N * n2, NAN);
    CHECK(k.follow(S.y.data(), S.z.data(), m, every, lam.data(), nullptr, nullptr, n2, n) == ContactStatus::ok,
          "%s: follow to %zu", what, m);
    const History h0 = history(k);
    const double bad_y[3] = {S.y[m], NAN, S.y[m + 1]}, bad_z[3] = {S.z[m], S.z[m], S.z[m + 1]};
    std::vector<double> out(3 * n2, 7.0), out0(out);
    std::vector<std::int8_t> sout(3 * n, 5), sout0(sout);
    ContactStatus st = k.follow(bad_y, bad_z, 3, every, out.data(), out.data(), sout.data(), n2, n);
    CHECK(st == ContactStatus::non_finite_position && k.error_info() == 1, "%s: NaN plate_y in follow: status %d at %ld",
          what, static_cast<int>(st), k.error_info());
    CHECK(bits_equal(out, out0) && bits_equal(sout, sout0), "%s: a rejected follow wrote its outputs", what);
    CHECK(same_history(history(k), h0), "%s: history changed by a rejected follow", what);
    const double inf_z[2] = {S.z[m], -INFINITY};
    st = k.follow(S.y.data() + m, inf_z, 2, every, nullptr, nullptr, nullptr, 0, 0);
    CHECK(st == ContactStatus::non_finite_position && k.error_info() == 1, "%s: -Inf plate_z in follow: status %d",
          what, static_cast<int>(st));
    st = k.step(INFINITY, S.z[m], every);
    CHECK(st == ContactStatus::non_finite_position, "%s: Inf plate_y in step: status %d", what, static_cast<int>(st));
    st = k.step(S.y[m], NAN, every);
    CHECK(st == ContactStatus::non_finite_position, "%s: NaN plate_z in step: status %d", what, static_cast<int>(st));
    CHECK(same_history(history(k), h0), "%s: history changed by a rejected step", what);
    st = k.follow(S.y.data() + m, S.z.data() + m, N - m, every, lam.data() + m * n2, nullptr, nullptr, n2, n);
    CHECK(st == ContactStatus::ok, "%s: follow on after the rejections: status %d", what, static_cast<int>(st));
    CHECK(bits_equal(lam, run), "%s: the path after the rejections differs from the one without them", what);
}

// The first sample of gross slip in the reference (touching, none stuck), N if none.
static std::size_t gross_slip(const Setup& S, const Ref& ref) {
    for (std::size_t t = 0; t < S.N; ++t) {
        bool touch = false, stick = false;
        for (std::size_t i = 0; i < S.n; ++i) {
            touch |= ref.state[t * S.n + i] != tactile::kContactOpen;
            stick |= ref.state[t * S.n + i] == tactile::kContactStick;
        }
        if (touch && !stick) return t;
    }
    return S.N;
}

// A kernel that cannot iterate (max_iter = max_active_set_iter = 0) follows the
// pieces and events but fails at a breakaway cascade. (1) The whole path in one call:
// it fails at the first breakaway, the history is the pristine one, the samples
// before are written. (2) Sample by sample, each sample first with those parameters:
// at a failure the history is unchanged; the sample is then stepped with the normal
// parameters (after restore(), which must change nothing). The failures mark the
// samples where a cascade ran; every sample where a node broke away must be one, the
// gross slip's too. The forces and statuses are the reference's.
static void check_cascade_failures(const Setup& S, const Ref& ref, bool every, const char* what) {
    const std::size_t n = S.n, N = S.N, n2 = 2 * n;
    // samples where a stuck node starts to slip (a breakaway: a cascade runs there)
    std::vector<char> breakaway(N, 0);
    std::size_t first_breakaway = N;
    for (std::size_t t = 1; t < N; ++t) {
        for (std::size_t i = 0; i < n; ++i)
            if (ref.state[(t - 1) * n + i] == tactile::kContactStick && ref.state[t * n + i] == tactile::kContactSlip)
                breakaway[t] = 1;
        if (breakaway[t] && first_breakaway == N) first_breakaway = t;
    }
    const std::size_t gross = gross_slip(S, ref);
    CHECK(first_breakaway < N && gross < N, "%s: the path has no breakaway (%zu) or no gross slip (%zu)", what,
          first_breakaway, gross);
    if (first_breakaway == N || gross == N) return;

    // (1) one call
    {
        ContactSolverKernel k = S.make();
        S.crippled(k);
        const History h0 = history(k);
        std::vector<double> lam(N * n2, NAN);
        std::vector<std::int8_t> state(N * n, -1);
        const ContactStatus st = k.follow(S.y.data(), S.z.data(), N, every, lam.data(), nullptr, state.data(), n2, n);
        CHECK(st == ContactStatus::no_convergence, "%s: crippled follow: status %d", what, static_cast<int>(st));
        CHECK(same_history(history(k), h0), "%s: history changed by the failed follow", what);
        CHECK(k.error_y() > S.y[first_breakaway - 1] && k.error_y() <= S.y[first_breakaway],
              "%s: failure at y = %.17g, not in the first breakaway's sample %zu", what, k.error_y(), first_breakaway);
        long mismatch = 0;
        const double dev = compare_rows(S, ref, lam.data(), state.data(), 0, first_breakaway, &mismatch);
        CHECK(dev <= kRtol * ref.peak && mismatch == 0, "%s: rows before the failure: deviation %.3g, %ld statuses",
              what, dev / ref.peak, mismatch);
    }
    // (2) sample by sample
    ContactSolverKernel k = S.make();
    std::vector<double> lam(N * n2, NAN);
    std::vector<std::int8_t> state(N * n, -1);
    long fails = 0, missed = 0, unchanged_bad = 0;
    std::size_t first_fail = N;
    for (std::size_t t = 0; t < N; ++t) {
        const History h0 = history(k);
        S.crippled(k);
        ContactStatus st = step_into(S, k, t, every, lam.data() + t * n2, state.data() + t * n);
        S.normal(k);
        if (st != ContactStatus::ok) {
            ++fails;
            if (first_fail == N) first_fail = t;
            CHECK(st == ContactStatus::no_convergence, "%s: sample %zu: status %d", what, t, static_cast<int>(st));
            unchanged_bad += !same_history(history(k), h0);
            k.restore();  // the slot holds the history before the failed step
            unchanged_bad += !same_history(history(k), h0);
            st = step_into(S, k, t, every, lam.data() + t * n2, state.data() + t * n);
            if (st != ContactStatus::ok) {
                CHECK(false, "%s: sample %zu after the failure: status %d", what, t, static_cast<int>(st));
                return;
            }
        } else {
            missed += breakaway[t];
        }
    }
    CHECK(unchanged_bad == 0, "%s: a failed step changed the history (%ld)", what, unchanged_bad);
    CHECK(first_fail == first_breakaway, "%s: first failure at %zu, first breakaway at %zu", what, first_fail,
          first_breakaway);
    CHECK(missed == 0, "%s: %ld samples with a breakaway ran no cascade", what, missed);
    long nb = 0;
    for (char b : breakaway) nb += b;
    long mismatch = 0;
    const double dev = compare_rows(S, ref, lam.data(), state.data(), 0, N, &mismatch);
    CHECK(dev <= kRtol * ref.peak, "%s: forces after the failures deviate by %.3g of the peak", what, dev / ref.peak);
    CHECK(mismatch == 0, "%s: statuses after the failures differ at %ld samples", what, mismatch);
    std::printf("%s: cascades failed without iterations at %ld samples (breakaways at %ld, the first at %zu, "
                "gross slip at %zu); stepped on: max |lam - module| %.3g of the peak\n",
                what, fails, nb, first_breakaway, gross, dev / ref.peak);
}

// A pad undoes a ridge that succeeded when another failed (restore): follow to a, save
// the history, follow [a, b) (across the gross-slip cascade), restore; the history is
// the saved one and the path from a is the run's without the undone stretch (to
// round-off: the factors and cached responses the stretch left are not the same).
static void check_restore(const Setup& S, const Ref& ref, bool every, std::size_t a, std::size_t b,
                          const char* what) {
    const std::size_t n = S.n, N = S.N, n2 = 2 * n;
    const std::vector<double> run = run_split(S, every, a);
    ContactSolverKernel k = S.make();
    std::vector<double> lam(N * n2, NAN);
    std::vector<std::int8_t> state(N * n, -1);
    CHECK(k.follow(S.y.data(), S.z.data(), a, every, lam.data(), nullptr, state.data(), n2, n) == ContactStatus::ok,
          "%s: follow to %zu", what, a);
    const History h0 = history(k);
    const long e0 = k.events();
    CHECK(k.follow(S.y.data() + a, S.z.data() + a, b - a, every, lam.data() + a * n2, nullptr, state.data() + a * n, n2,
                   n) == ContactStatus::ok,
          "%s: follow [%zu, %zu)", what, a, b);
    CHECK(k.events() > e0, "%s: no event in [%zu, %zu)", what, a, b);
    k.restore();
    CHECK(same_history(history(k), h0), "%s: restore() did not bring the history back", what);
    const ContactStatus st =
        k.follow(S.y.data() + a, S.z.data() + a, N - a, every, lam.data() + a * n2, nullptr, state.data() + a * n, n2, n);
    CHECK(st == ContactStatus::ok, "%s: follow on after restore: status %d", what, static_cast<int>(st));
    long mismatch = 0;
    const double dev = compare_rows(S, ref, lam.data(), state.data(), 0, N, &mismatch);
    CHECK(dev <= kRtol * ref.peak, "%s: forces after restore deviate by %.3g of the peak", what, dev / ref.peak);
    CHECK(mismatch == 0, "%s: statuses after restore differ at %ld samples", what, mismatch);
    double drun = 0.0;
    for (std::size_t i = 0; i < N * n2; ++i) drun = std::fmax(drun, std::fabs(lam[i] - run[i]));
    CHECK(drun <= kRtol * ref.peak, "%s: after restore %.3g of the peak from the run without the stretch", what,
          drun / ref.peak);
    std::printf("%s: [%zu, %zu) undone by restore(), then followed on: %.3g of the peak from the run without it\n",
                what, a, b, drun / ref.peak);
}

int main(int argc, char** argv) {
    if (argc != 2) {
        std::fprintf(stderr, "usage: %s reference.bin\n", argv[0]);
        return 2;
    }
    std::FILE* f = std::fopen(argv[1], "rb");
    if (!f) return 2;
    Setup S;
    const auto head = read<std::uint64_t>(f, 4);
    S.n = head[0];
    S.N = head[1];
    S.max_iter = static_cast<int>(head[2]);
    S.max_as = static_cast<int>(head[3]);
    const auto par = read<double>(f, 9);
    S.r = par[0]; S.w_tol = par[1]; S.mu = par[2]; S.mu_k = par[3]; S.tol = par[4];
    S.g_tol = par[5]; S.f_tol = par[6]; S.evt_g_tol = par[7]; S.evt_f_tol = par[8];
    const std::size_t n = S.n, N = S.N;
    S.C = read<double>(f, 4 * n * n);
    S.z0 = read<double>(f, n);
    S.w = read<double>(f, n);
    S.y = read<double>(f, N);
    S.z = read<double>(f, N);
    Ref refs[3];  // follow every, follow auto, step auto
    for (Ref& r : refs) {
        r.lam = read<double>(f, N * 2 * n);
        r.state = read<std::int8_t>(f, N * n);
        const auto c = read<std::int64_t>(f, 4);
        r.solves = static_cast<long>(c[0]);
        r.events = static_cast<long>(c[1]);
        r.factorizations = static_cast<long>(c[2]);
        r.updates = static_cast<long>(c[3]);
        r.peak = 0.0;
        for (double v : r.lam) r.peak = std::fmax(r.peak, std::fabs(v));
    }
    std::fclose(f);
    std::printf("%zu nodes, %zu samples, kernels %s\n", n, N, tactile::contact_simd_path());

    for (const bool every : {true, false}) {
        const Ref& rf = refs[every ? 0 : 1];
        const Ref& rs = every ? refs[0] : refs[2];  // step(every) is follow of one sample
        const char* tag = every ? "every" : "auto";
        char what[64];
        std::snprintf(what, sizeof what, "%s follow", tag);
        const std::vector<double> run = run_follow(S, rf, every, what);
        std::snprintf(what, sizeof what, "%s projected", tag);
        check_projected(S, rf, every, run, what);
        std::snprintf(what, sizeof what, "%s step", tag);
        const std::vector<double> steps = run_step(S, rs, every, what);
        if (every) CHECK(bits_equal(steps, run), "every: step() differs from follow()");
        std::snprintf(what, sizeof what, "%s non-finite", tag);
        check_non_finite(S, every, what);
        std::snprintf(what, sizeof what, "%s cascade failures", tag);
        check_cascade_failures(S, rs, every, what);
        std::snprintf(what, sizeof what, "%s restore", tag);
        const std::size_t g = gross_slip(S, rf);
        CHECK(g >= 50 && g + 25 <= N, "%s: gross slip at %zu", tag, g);
        if (g >= 50 && g + 25 <= N) check_restore(S, rf, every, g - 50, g + 25, what);
        // the baseline kernels (16-byte vectors, no FMA) on the same path
        tactile::simd::set_baseline(true);
        std::snprintf(what, sizeof what, "%s follow (%s)", tag, tactile::contact_simd_path());
        run_follow(S, rf, every, what);
        tactile::simd::set_baseline(false);
    }
    std::printf("%s: %d failures\n", failures ? "FAILED" : "ok", failures);
    return failures ? 1 : 0;
}
