// Bindings of the condensed contact solver (contact_solver.hpp).
//
// _core._ContactSolver(compliance, node_z, weights, r, w_tol)   one ridge
//   set_params(mu, mu_kinetic, tol, max_iter, max_active_set_iter)
//   set_event_tolerances(g_tol, f_tol, evt_g_tol, evt_f_tol)
//   step(plate_y, plate_z, every=True) -> (status, forces, displacement, state, slip_fraction, iterations)
//       status 0: the arrays are new copies of the result; else they are None and
//       error() gives (info, residual, tolerance), error_point() the load point (y, z)
//   follow(plate_y[N], plate_z[N], every, lam_out, u_out, state_out) -> (status, solves, events)
//       the event-driven path following over a trajectory, without the GIL, into
//       preallocated arrays (each may be None)
//   error(), reset(), get_history(), set_history(...), solves, events
// _core._ContactPad(solvers)   several ridges stepped in one call, without the GIL
//   step(plate_y, plate_z[n_ridges], every=True) -> (status, ridge, solves, forces, displacement,
//       state, slip_fraction, touching, gross_slip, sum f_t, sum f_n); the ridges keep the step
//       only if every one succeeded.
//   follow(plate_y[T], plate_z[T, n_ridges], every, lam, displacement, state,
//       slip_fraction, threads, proj, proj_out, flags) -> (status, ridge, solves, events):
//       each ridge follows
//       the whole trajectory ("auto" or "every"); the ridges are independent, so with
//       threads = 2 they are shared with a second thread (shared_list.hpp; same results).
//   A ridge with the configuration, history and plate path of an earlier ridge of the
//   pad (the mirror-image ridges under a symmetric finger) is that ridge's shadow: it
//   gets its results without computing them (see PyContact); sources tells which.
// _contact_simd_path(): the kernel variant (AVX2+FMA or baseline) the contact kernels
//   run now (the process-wide baseline switch, module.cpp's _set_baseline, forces the baseline).
// The Python-facing classes are tactile_mirror.contact.ContactSolver and Pad, which
// validate arguments and turn a status into the reference implementation's exceptions.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <atomic>
#include <cstdint>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "contact_solver.hpp"
#include "shared_list.hpp"

namespace py = pybind11;
using tactile::ContactSolverKernel;
using tactile::ContactStatus;

namespace {

using F64 = py::array_t<double, py::array::c_style | py::array::forcecast>;
using I8 = py::array_t<std::int8_t, py::array::c_style>;

// A ridge. A pad's ridges under a symmetric finger come in mirror-image pairs with the
// same plate path (and under a flat finger all of them): a ridge of a pad that has the
// same configuration, history and plate path as an earlier ridge of that pad is that
// ridge's shadow (`master`). A shadow computes nothing: its results are the master's
// (the kernel is deterministic, so they are the bits it would compute itself), its
// read-only accessors read the master's kernel (`view`), and it becomes a kernel of its
// own again (`detach`: a copy of the master's) before anything changes it or its
// master from outside the pad, or when the pad gives it a path of its own.
struct PyContact {
    ContactSolverKernel k;
    std::atomic<bool> busy{false};  // one call at a time: the pad steps without the GIL
    std::shared_ptr<PyContact> master;  // non-null: a shadow of master
    std::vector<PyContact*> shadows;     // the ridges shadowing this one
    template <typename... A>
    explicit PyContact(A&&... a) : k(std::forward<A>(a)...) {}
    PyContact(const PyContact&) = delete;
    PyContact& operator=(const PyContact&) = delete;
    ~PyContact() { unlink(); }
    const ContactSolverKernel& view() const noexcept { return master ? master->k : k; }
    // drop the link to the master without copying (the caller has made k current)
    void unlink() noexcept {
        if (!master) return;
        auto& v = master->shadows;
        for (std::size_t i = 0; i < v.size(); ++i)
            if (v[i] == this) { v.erase(v.begin() + static_cast<std::ptrdiff_t>(i)); break; }
        master.reset();
    }
    // a kernel of its own again: the master's state copied (the same bits it would hold)
    void detach() {
        if (!master) return;
        k = master->k;
        unlink();
    }
    // before this ridge changes from outside its pad: it and its shadows get kernels of their own
    void detach_all() {
        detach();
        while (!shadows.empty()) shadows.back()->detach();
    }
};

// Every ridge of a pad busy for one call (nothing allocated): throws, with the ridges
// taken so far released, if one of them is being used by another thread.
class BusyAll {
public:
    explicit BusyAll(const std::vector<std::shared_ptr<PyContact>>& r) : r_(r) {
        for (; n_ < r_.size(); ++n_)
            if (r_[n_]->busy.exchange(true)) {
                release();
                throw std::runtime_error("this contact solver is being used by another thread");
            }
    }
    BusyAll(const BusyAll&) = delete;
    BusyAll& operator=(const BusyAll&) = delete;
    ~BusyAll() { release(); }

private:
    void release() noexcept {
        for (std::size_t k = 0; k < n_; ++k) r_[k]->busy.store(false);
        n_ = 0;
    }
    const std::vector<std::shared_ptr<PyContact>>& r_;
    std::size_t n_ = 0;
};

class Busy {
public:
    explicit Busy(PyContact& c) : c_(&c) {
        if (c.busy.exchange(true)) throw std::runtime_error("this contact solver is being used by another thread");
    }
    Busy(Busy&& o) noexcept : c_(o.c_) { o.c_ = nullptr; }
    Busy(const Busy&) = delete;
    ~Busy() {
        if (c_) c_->busy.store(false);
    }

private:
    PyContact* c_;
};

F64 vector_arg(const py::handle& obj, std::size_t n, const char* name) {
    F64 a = F64::ensure(obj);
    if (!a) throw py::type_error(std::string(name) + " must be an array of real numbers");
    if (a.ndim() != 1 || static_cast<std::size_t>(a.shape(0)) != n)
        throw py::value_error(std::string(name) + " must have shape (" + std::to_string(n) + ",)");
    return a;
}

py::array_t<double> copy_out(const double* p, std::size_t m) {
    py::array_t<double> a(static_cast<py::ssize_t>(m));
    std::memcpy(a.mutable_data(), p, m * sizeof(double));
    return a;
}

py::array_t<std::int8_t> copy_out8(const std::int8_t* p, std::size_t m) {
    py::array_t<std::int8_t> a(static_cast<py::ssize_t>(m));
    std::memcpy(a.mutable_data(), p, m);
    return a;
}

// A preallocated output: None (nullptr) or a writeable C-contiguous array of dtype T
// with rows * per_row entries and rows on its first axis.
// The plate path of a whole-trajectory pad call: plate_y (T,) and plate_z (T, n_ridges),
// float64 C-contiguous (converted if needed). Returns T.
std::size_t pad_plate_path(py::handle plate_y, py::handle plate_z, std::size_t R, F64& y, F64& z) {
    y = F64::ensure(plate_y);
    if (!y || y.ndim() != 1) throw py::value_error("plate_y must be a 1-D array");
    const std::size_t T = static_cast<std::size_t>(y.shape(0));
    z = F64::ensure(plate_z);
    if (!z || z.ndim() != 2 || static_cast<std::size_t>(z.shape(0)) != T ||
        static_cast<std::size_t>(z.shape(1)) != R)
        throw py::value_error("plate_z must have shape (" + std::to_string(T) + ", " + std::to_string(R) + ")");
    return T;
}

template <typename T>
T* out_rows(py::handle h, const char* name, std::size_t rows, std::size_t per_row) {
    if (h.is_none()) return nullptr;
    if (!py::isinstance<py::array_t<T>>(h))
        throw py::type_error(std::string(name) + " must be a numpy array of dtype " +
                             std::string(py::str(py::dtype::of<T>())));
    py::array g = py::reinterpret_borrow<py::array>(h);
    if (!g.writeable() || static_cast<std::size_t>(g.size()) != rows * per_row || !(g.flags() & py::array::c_style) ||
        g.ndim() < 1 || g.shape(0) != static_cast<py::ssize_t>(rows))
        throw py::value_error(std::string(name) + " must be a writeable C-contiguous array of " + std::to_string(rows) +
                              " x " + std::to_string(per_row) + " entries");
    return static_cast<T*>(g.mutable_data());
}

}  // namespace

void tm_bind_contact(py::module_& m) {
    py::class_<PyContact, std::shared_ptr<PyContact>>(
        m, "_ContactSolver", "Condensed contact solver of one ridge. Use tactile_mirror.contact.ContactSolver.")
        .def(py::init([](py::handle compliance, py::handle node_z, py::handle weights, double r, double w_tol) {
                 F64 z = F64::ensure(node_z);
                 if (!z || z.ndim() != 1 || z.shape(0) < 1)
                     throw py::value_error("node_z must be a non-empty 1-D array");
                 const std::size_t n = static_cast<std::size_t>(z.shape(0));
                 F64 C = F64::ensure(compliance);
                 if (!C || C.ndim() != 2 || static_cast<std::size_t>(C.shape(0)) != 2 * n ||
                     static_cast<std::size_t>(C.shape(1)) != 2 * n)
                     throw py::value_error("compliance must have shape (2n, 2n) for n = len(node_z)");
                 F64 w = vector_arg(weights, n, "weights");
                 if (!(r > 0) || !(w_tol >= 0)) throw py::value_error("r must be > 0 and w_tol >= 0");
                 return std::make_shared<PyContact>(n, C.data(), z.data(), w.data(), r, w_tol);
             }),
             py::arg("compliance"), py::arg("node_z"), py::arg("weights"), py::arg("r"), py::arg("w_tol"))
        .def_property_readonly("n_nodes", [](const PyContact& c) { return c.k.n_nodes(); })
        .def_property_readonly("r", [](const PyContact& c) { return c.k.r(); })
        .def_property_readonly("factorizations", [](PyContact& c) { Busy b(c); return c.view().factorizations(); },
                               "piece LU factorisations since construction")
        .def_property_readonly("affine_steps", [](PyContact& c) { Busy b(c); return c.view().affine_steps(); },
                               "piece solves served by the affine response of an unchanged piece")
        .def_property_readonly("rhs_reuses", [](PyContact& c) { Busy b(c); return c.view().rhs_reuses(); },
                               "base solves of a load's right-hand side served by the previous one (the "
                               "iterations of one load point)")
        .def_property_readonly("updates", [](PyContact& c) { Busy b(c); return c.view().updates(); },
                               "pieces solved by bordering the factored base piece instead of refactoring")
        .def("set_params",
             [](PyContact& c, double mu, double mu_kinetic, double tol, int max_iter, int max_as) {
                 Busy b(c);
                 c.detach_all();
                 c.k.params = {mu, mu_kinetic, tol, max_iter, max_as};
             },
             py::arg("mu"), py::arg("mu_kinetic"), py::arg("tol"), py::arg("max_iter"),
             py::arg("max_active_set_iter"))
        .def("step",
             [](PyContact& c, double plate_y, double plate_z, bool every) -> py::tuple {
                 Busy b(c);
                 c.detach_all();
                 const ContactStatus s = c.k.step(plate_y, plate_z, every);
                 if (s != ContactStatus::ok)
                     return py::make_tuple(static_cast<int>(s), py::none(), py::none(), py::none(), 0.0, 0);
                 const std::size_t n = c.k.n_nodes();
                 return py::make_tuple(0, copy_out(c.k.forces(), 2 * n), copy_out(c.k.displacement(), 2 * n),
                                       copy_out8(c.k.reported_state(), n), c.k.slip_fraction(), c.k.iterations());
             },
             py::arg("plate_y"), py::arg("plate_z"), py::arg("every") = true)
        .def("error",
             [](PyContact& c) {
                 Busy b(c);
                 const ContactSolverKernel& k = c.view();
                 return py::make_tuple(k.error_info(), k.error_residual(), k.error_tolerance());
             },
             "(info, residual, tolerance) of the last failed step")
        .def("error_point", [](PyContact& c) { Busy b(c); return py::make_tuple(c.view().error_y(), c.view().error_z()); },
             "load point (plate_y, plate_z) of the last failure inside follow (cascade or status cycle)")
        .def_property_readonly("solves", [](PyContact& c) { Busy b(c); return c.view().solves(); },
                               "linear solves of the path following since the last reset")
        .def_property_readonly("events", [](PyContact& c) { Busy b(c); return c.view().events(); },
                               "points where node statuses changed since the last reset")
        .def("set_event_tolerances",
             [](PyContact& c, double g_tol, double f_tol, double evt_g_tol, double evt_f_tol) {
                 if (!(g_tol >= 0) || !(f_tol >= 0) || !(evt_g_tol >= 0) || !(evt_f_tol >= 0))
                     throw py::value_error("event tolerances must be >= 0");
                 Busy b(c);
                 c.detach_all();
                 c.k.set_event_tolerances(g_tol, f_tol, evt_g_tol, evt_f_tol);
             },
             py::arg("g_tol"), py::arg("f_tol"), py::arg("evt_g_tol"), py::arg("evt_f_tol"))
        .def("follow",
             [](PyContact& c, py::handle plate_y, py::handle plate_z, bool every, py::handle lam_out,
                py::handle u_out, py::handle state_out) -> py::tuple {
                 const std::size_t n = c.k.n_nodes();
                 F64 y = F64::ensure(plate_y), z = F64::ensure(plate_z);
                 if (!y || y.ndim() != 1) throw py::value_error("plate_y must be a 1-D array");
                 const std::size_t N = static_cast<std::size_t>(y.shape(0));
                 if (!z || z.ndim() != 1 || static_cast<std::size_t>(z.shape(0)) != N)
                     throw py::value_error("plate_z must have the shape of plate_y");
                 double* lo = out_rows<double>(lam_out, "lam_out", N, 2 * n);
                 double* uo = out_rows<double>(u_out, "u_out", N, 2 * n);
                 std::int8_t* so = out_rows<std::int8_t>(state_out, "state_out", N, n);
                 Busy b(c);
                 c.detach_all();
                 const long s0 = c.k.solves(), e0 = c.k.events();
                 ContactStatus st;
                 {
                     py::gil_scoped_release nogil;
                     st = c.k.follow(y.data(), z.data(), N, every, lo, uo, so, 2 * n, n);
                 }
                 return py::make_tuple(static_cast<int>(st), c.k.solves() - s0, c.k.events() - e0);
             },
             py::arg("plate_y"), py::arg("plate_z"), py::arg("every"), py::arg("lam_out"), py::arg("u_out"),
             py::arg("state_out"),
             "Follow the samples (plate_y[k], plate_z[k]) from the current state: every=True solves at every "
             "sample, False only at events. Rows k of lam_out, u_out ((N, 2n) float64) and state_out ((N, n) "
             "int8), each None or a writeable C-contiguous array, get the forces (lt, ln), displacements and "
             "statuses of sample k. Returns (status, solves, events); on status != 0 the history is unchanged "
             "(error() and error_point() give the details; for status 1 error()[0] is the sample).")
        .def("reset",
             [](PyContact& c) {
                 Busy b(c);
                 c.unlink();  // its own state is about to be the reset one: nothing to copy
                 while (!c.shadows.empty()) c.shadows.back()->detach();
                 c.k.reset();
             })
        .def("get_history",
             [](PyContact& c) {
                 // Reads are claimed as writes are: while a pad's follow() runs without the
                 // GIL, a read would return the middle of a step.
                 Busy b(c);
                 const ContactSolverKernel& k = c.view();
                 const std::size_t n = k.n_nodes();
                 py::array_t<bool> sliding(static_cast<py::ssize_t>(n));
                 for (std::size_t i = 0; i < n; ++i) sliding.mutable_data()[i] = k.state()[i] == tactile::kContactSlip;
                 py::dict d;
                 d["lam"] = copy_out(k.lam(), 2 * n);
                 d["uy_prev"] = copy_out(k.path_displacement(), n);
                 d["s_prev"] = k.s_prev();
                 d["state"] = copy_out8(k.state(), n);
                 d["sign"] = copy_out(k.sign(), n);
                 d["sliding"] = sliding;
                 d["z_prev"] = k.placed() ? py::object(py::float_(k.z_prev())) : py::object(py::none());
                 return d;
             })
        .def("set_history",
             [](PyContact& c, py::handle lam, py::handle uy_prev, double s_prev, py::handle state, py::handle sign,
                py::handle sliding, py::object z_prev) {
                 const std::size_t n = c.k.n_nodes();
                 F64 l = vector_arg(lam, 2 * n, "lam"), u = vector_arg(uy_prev, n, "uy_prev"),
                     sg = vector_arg(sign, n, "sign");
                 auto st = py::array_t<std::int8_t, py::array::c_style | py::array::forcecast>::ensure(state);
                 auto sl = py::array_t<std::uint8_t, py::array::c_style | py::array::forcecast>::ensure(sliding);
                 if (!st || st.ndim() != 1 || static_cast<std::size_t>(st.shape(0)) != n)
                     throw py::value_error("state must have shape (" + std::to_string(n) + ",)");
                 if (!sl || sl.ndim() != 1 || static_cast<std::size_t>(sl.shape(0)) != n)
                     throw py::value_error("sliding must have shape (" + std::to_string(n) + ",)");
                 for (std::size_t i = 0; i < n; ++i)
                     if (st.data()[i] < 0 || st.data()[i] > 2) throw py::value_error("state entries must be 0, 1 or 2");
                 const bool has_z = !z_prev.is_none();
                 const double zp = has_z ? z_prev.cast<double>() : 0.0;
                 Busy b(c);
                 c.detach_all();
                 // uy_prev and sliding are checked but derived: the displacements are C P lam,
                 // the sliding nodes those with the status SLIP
                 c.k.set_path_history(l.data(), sg.data(), st.data(), s_prev, has_z, zp);
             },
             py::arg("lam"), py::arg("uy_prev"), py::arg("s_prev"), py::arg("state"), py::arg("sign"),
             py::arg("sliding"), py::arg("z_prev") = py::none());

    // The ridges of a pad. Before every call, `link` decides which ridges shadow an
    // earlier one (PyContact): a shadow keeps its link while its plate path is its
    // master's, sample for sample; an unlinked ridge becomes the shadow of an earlier
    // unlinked one when both are pristine (just built or reset), of the same
    // configuration, and get the same path. The call then steps the masters only and
    // copies their results to the shadows' rows.
    struct PyContactPad {
        std::vector<std::shared_ptr<PyContact>> ridges;
        std::size_t n = 0;
        std::vector<std::size_t> src;  // src[k]: the ridge whose results ridge k gets (k itself if it computes)
        std::vector<long> solved;      // step: the solves of each ridge in this call
        std::vector<ContactStatus> status;  // step: the status of each computing ridge
        std::vector<char> ran;         // step: the ridges stepped in this call (those after a failure may not be)
        std::vector<std::size_t> own;  // the computing ridges (src[k] == k), in order
        // threads = 2: the computing ridges shared with a second thread kept by the pad
        tactile::SharedList workers;
        PyContactPad() = default;
        PyContactPad(PyContactPad&&) = default;
        ~PyContactPad() {
            for (auto& r : ridges) r->detach();  // a shadow is only valid inside its pad
        }
        // plate heights of ridge k: zk[t * stride]
        void link(const double* z, std::size_t T, std::size_t stride_t, std::size_t stride_k) {
            const std::size_t R = ridges.size();
            auto same_path = [&](std::size_t j, std::size_t k) {
                for (std::size_t t = 0; t < T; ++t)
                    if (!(z[t * stride_t + j * stride_k] == z[t * stride_t + k * stride_k])) return false;
                return true;
            };
            src.resize(R);
            solved.resize(R);
            ran.resize(R);
            status.resize(R);
            for (std::size_t k = 0; k < R; ++k) {
                PyContact& c = *ridges[k];
                src[k] = k;
                if (c.master) {
                    std::size_t j = 0;
                    while (j < k && ridges[j].get() != c.master.get()) ++j;
                    if (j < k && same_path(j, k)) {
                        src[k] = j;
                        continue;
                    }
                    c.detach();
                }
                if (!c.shadows.empty() || !c.k.pristine()) continue;
                for (std::size_t j = 0; j < k; ++j) {
                    PyContact& m = *ridges[j];
                    if (src[j] != j || m.master || !m.k.pristine() || !same_path(j, k) || !m.k.same_config(c.k))
                        continue;
                    c.master = ridges[j];
                    m.shadows.push_back(&c);
                    src[k] = j;
                    break;
                }
            }
        }
    };
    py::class_<PyContactPad>(m, "_ContactPad", "Ridges of a pad stepped in one call. Use tactile_mirror.contact.Pad.")
        .def(py::init([](const py::sequence& solvers) {
                 if (py::len(solvers) == 0) throw py::value_error("solvers must not be empty");
                 PyContactPad p;
                 for (const py::handle h : solvers) {
                     if (!py::isinstance<PyContact>(h))
                         throw py::type_error("solvers must hold _ContactSolver objects");
                     p.ridges.push_back(h.cast<std::shared_ptr<PyContact>>());
                 }
                 p.n = p.ridges[0]->k.n_nodes();
                 for (const auto& r : p.ridges)
                     if (r->k.n_nodes() != p.n) throw py::value_error("solvers must all have the same number of nodes");
                 for (std::size_t k = 0; k < p.ridges.size(); ++k)
                     for (std::size_t j = 0; j < k; ++j)
                         if (p.ridges[j] == p.ridges[k]) throw py::value_error("solvers must be distinct objects");
                 return p;
             }),
             py::arg("solvers"))
        .def_property_readonly("n_ridges", [](const PyContactPad& p) { return p.ridges.size(); })
        .def_property_readonly("sources", [](const PyContactPad& p) {
                                   py::tuple t(p.src.size());
                                   for (std::size_t k = 0; k < p.src.size(); ++k) t[k] = p.src[k];
                                   return t;
                               },
                               "of the last call, per ridge: the ridge whose results it got (itself, or the earlier "
                               "ridge with the same configuration, history and plate path it shadows)")
        .def("step",
             [](PyContactPad& p, double plate_y, py::handle plate_z, bool every, int threads) -> py::tuple {
                 const std::size_t R = p.ridges.size(), n = p.n;
                 F64 z = vector_arg(plate_z, R, "plate_z");
                 if (threads < 1) throw py::value_error("threads must be >= 1");
                 BusyAll locks(p.ridges);
                 py::array_t<double> forces({static_cast<py::ssize_t>(R), static_cast<py::ssize_t>(2 * n)});
                 py::array_t<double> disp({static_cast<py::ssize_t>(R), static_cast<py::ssize_t>(2 * n)});
                 py::array_t<std::int8_t> state({static_cast<py::ssize_t>(R), static_cast<py::ssize_t>(n)});
                 py::array_t<double> frac(static_cast<py::ssize_t>(R));
                 py::array_t<bool> touch(static_cast<py::ssize_t>(R)), gross(static_cast<py::ssize_t>(R));
                 bool* to = touch.mutable_data();
                 bool* go = gross.mutable_data();
                 double sum_t = 0.0, sum_n = 0.0;
                 double* fo = forces.mutable_data();
                 double* dout = disp.mutable_data();
                 std::int8_t* so = state.mutable_data();
                 double* fr = frac.mutable_data();
                 const double* zp = z.data();
                 ContactStatus status = ContactStatus::ok;
                 std::size_t bad = R;
                 long its = 0;
                 p.link(zp, 1, 0, 1);  // with the GIL: the links are read by the solvers' accessors
                 p.own.clear();  // (capacity R after the first call: no allocation)
                 for (std::size_t k = 0; k < R; ++k)
                     if (p.src[k] == k) p.own.push_back(k);
                 auto step_ridge = [&](std::size_t k) noexcept -> bool {
                     ContactSolverKernel& s = p.ridges[k]->k;
                     const long s0 = s.solves();
                     double y = plate_y;
                     const ContactStatus st = s.follow(&y, zp + k, 1, every, fo + k * 2 * n, dout + k * 2 * n,
                                                       so + k * n, 0, 0);
                     p.ran[k] = 1;
                     p.status[k] = st;
                     if (st != ContactStatus::ok) return false;
                     p.solved[k] = s.solves() - s0;
                     s.report(fo + k * 2 * n, so + k * n, fo + k * 2 * n, fr[k]);
                     return true;
                 };
                 {
                     py::gil_scoped_release nogil;
                     for (std::size_t k = 0; k < R; ++k) p.ran[k] = 0;  // (status[k] is read only where ran[k])
                     p.workers.run(p.own.data(), p.own.size(), step_ridge, threads >= 2);
                     // the first failing ridge (every ridge before it ran, on either thread;
                     // those after it may not have); every other ridge that stepped steps back:
                     // the pad keeps the tick only if every ridge succeeded
                     for (std::size_t k = 0; k < R && bad == R; ++k)
                         if (p.ran[k] && p.status[k] != ContactStatus::ok) bad = k;
                     if (bad < R) {
                         status = p.status[bad];
                         for (std::size_t k : p.own)
                             if (k != bad && p.ran[k] && p.status[k] == ContactStatus::ok) p.ridges[k]->k.restore();
                     } else {
                         for (std::size_t k = 0; k < R; ++k) {
                             const std::size_t j = p.src[k];
                             its += p.solved[j];
                             if (j == k) continue;  // a shadow: its master's results
                             std::memcpy(fo + k * 2 * n, fo + j * 2 * n, 2 * n * sizeof(double));
                             std::memcpy(dout + k * 2 * n, dout + j * 2 * n, 2 * n * sizeof(double));
                             std::memcpy(so + k * n, so + j * n, n);
                             fr[k] = fr[j];
                         }
                         // what a pad state reads: touch, gross slip, force sums
                         for (std::size_t q = 0; q < R; ++q) {
                             const std::int8_t* sq = so + q * n;
                             bool any = false, stick = false;
                             for (std::size_t i = 0; i < n; ++i) {
                                 any |= sq[i] != tactile::kContactOpen;
                                 stick |= sq[i] == tactile::kContactStick;
                             }
                             to[q] = any;
                             go[q] = any && !stick;
                             const double* fq = fo + q * 2 * n;
                             for (std::size_t i = 0; i < n; ++i) { sum_t += fq[i]; sum_n += fq[n + i]; }
                         }
                     }
                 }
                 if (status != ContactStatus::ok)
                     return py::make_tuple(static_cast<int>(status), bad, 0, py::none(), py::none(), py::none(),
                                           py::none(), py::none(), py::none(), 0.0, 0.0);
                 return py::make_tuple(0, 0, its, forces, disp, state, frac, touch, gross, sum_t, sum_n);
             },
             py::arg("plate_y"), py::arg("plate_z"), py::arg("every") = true, py::arg("threads") = 1,
             "One sample for every ridge (every=False: from the unit responses while no status changes; "
             "threads=2: the computing ridges shared, one at a time, with a worker thread kept by the pad, the "
             "same bits); "
             "the ridges keep it only if every one succeeded. Returns (status, ridge, solves, forces f = (lt, -ln), "
             "displacement, state, slip_fraction, touching, gross_slip, sum of f_t, sum of f_n) (the sums over all "
             "ridges and nodes, N/m). A ridge with the configuration, history and "
             "plate height of an earlier one gets that ridge's results (the same bits) without computing them.")
        .def("follow",
             [](PyContactPad& p, py::handle plate_y, py::handle plate_z, bool every, py::handle lam,
                py::handle disp, py::handle state, py::handle frac, int threads, py::handle proj,
                py::handle proj_out, py::handle flags) -> py::tuple {
                 const std::size_t R = p.ridges.size(), n = p.n;
                 F64 y, z;
                 const std::size_t T = pad_plate_path(plate_y, plate_z, R, y, z);
                 if (threads < 1) throw py::value_error("threads must be >= 1");
                 double* lop = out_rows<double>(lam, "lam", T, R * 2 * n);
                 double* dop = out_rows<double>(disp, "displacement", T, R * 2 * n);
                 std::int8_t* sop = out_rows<std::int8_t>(state, "state", T, R * n);
                 double* frp = out_rows<double>(frac, "slip_fraction", T, R);
                 std::int8_t* flp = out_rows<std::int8_t>(flags, "flags", T, R);
                 F64 P;
                 std::size_t q = 0;
                 if (!proj.is_none()) {
                     P = F64::ensure(proj);
                     if (!P || P.ndim() != 2 || static_cast<std::size_t>(P.shape(1)) != 2 * n || P.shape(0) < 1)
                         throw py::value_error("proj must have shape (q, " + std::to_string(2 * n) + ")");
                     q = static_cast<std::size_t>(P.shape(0));
                 }
                 double* pop = out_rows<double>(proj_out, "proj_out", T, R * q);
                 if ((q == 0) != (pop == nullptr)) throw py::value_error("proj and proj_out go together");
                 BusyAll locks(p.ridges);
                 p.link(z.data(), T, R, 1);
                 std::vector<std::size_t> own;  // the ridges that compute
                 for (std::size_t k = 0; k < R; ++k)
                     if (p.src[k] == k) own.push_back(k);
                 for (std::size_t k : own) p.ridges[k]->k.set_projection(q ? P.data() : nullptr, q);
                 // the computing ridges' plate heights, contiguous
                 std::vector<double> zr(T * R);
                 for (std::size_t t = 0; t < T; ++t)
                     for (std::size_t k : own) zr[k * T + t] = z.data()[t * R + k];
                 std::vector<ContactStatus> st(R, ContactStatus::ok);
                 std::vector<char> ran(R, 0);  // the ridges after a failure may not run
                 long s0 = 0, e0 = 0;
                 for (auto& r : p.ridges) { s0 += r->view().solves(); e0 += r->view().events(); }
                 const double* yp = y.data();
                 auto ridge = [&](std::size_t k) noexcept -> bool {
                     ContactSolverKernel& s = p.ridges[k]->k;
                     ContactSolverKernel::Extra ex;
                     ex.proj = pop ? pop + k * q : nullptr;
                     ex.stride_q = R * q;
                     ex.frac = frp ? frp + k : nullptr;
                     ex.flags = flp ? flp + k : nullptr;
                     ex.stride_f = R;
                     st[k] = s.follow(yp, zr.data() + k * T, T, every, lop ? lop + k * 2 * n : nullptr,
                                      dop ? dop + k * 2 * n : nullptr, sop ? sop + k * n : nullptr, R * 2 * n, R * n,
                                      ex);
                     ran[k] = 1;
                     return st[k] == ContactStatus::ok;
                 };
                 {
                     py::gil_scoped_release nogil;
                     p.workers.run(own.data(), own.size(), ridge, threads >= 2);
                     for (std::size_t k = 0; k < R; ++k) {  // the shadows: their masters' rows
                         const std::size_t j = p.src[k];
                         if (j == k) continue;
                         st[k] = st[j];
                         if (!ran[j] || st[j] != ContactStatus::ok) continue;
                         for (std::size_t t = 0; t < T; ++t) {
                             const std::size_t o = t * R + k, oj = t * R + j;
                             if (lop) std::memcpy(lop + o * 2 * n, lop + oj * 2 * n, 2 * n * sizeof(double));
                             if (dop) std::memcpy(dop + o * 2 * n, dop + oj * 2 * n, 2 * n * sizeof(double));
                             if (sop) std::memcpy(sop + o * n, sop + oj * n, n);
                             if (pop) std::memcpy(pop + o * q, pop + oj * q, q * sizeof(double));
                             if (frp) frp[o] = frp[oj];
                             if (flp) flp[o] = flp[oj];
                         }
                     }
                 }
                 std::size_t bad = R;
                 for (std::size_t k = 0; k < R && bad == R; ++k)
                     if (st[k] != ContactStatus::ok) bad = k;
                 if (bad < R) {  // all ridges back to where they were
                     for (std::size_t k : own)
                         if (ran[k] && st[k] == ContactStatus::ok) p.ridges[k]->k.restore();
                     return py::make_tuple(static_cast<int>(st[bad]), bad, 0, 0);
                 }
                 long s1 = 0, e1 = 0;
                 for (auto& r : p.ridges) { s1 += r->view().solves(); e1 += r->view().events(); }
                 return py::make_tuple(0, 0, s1 - s0, e1 - e0);
             },
             py::arg("plate_y"), py::arg("plate_z"), py::arg("every"), py::arg("lam"), py::arg("displacement"),
             py::arg("state"), py::arg("slip_fraction"), py::arg("threads") = 1, py::arg("proj") = py::none(),
             py::arg("proj_out") = py::none(), py::arg("flags") = py::none(),
             "Every ridge follows the whole trajectory (every=True: a solve at every sample; False: at events "
             "only) without the GIL, into preallocated C-contiguous arrays, each of which may be None: lam and "
             "displacement (T, n_ridges, 2n) float64 (the forces (lt, ln), N/m, and the surface displacements), "
             "state (T, n_ridges, n) int8, slip_fraction (T, n_ridges) float64, flags (T, n_ridges) int8 (bit 0: "
             "some node touches; bit 1: gross slip, touching and none stuck), and with proj (q, 2n) float64, "
             "proj_out (T, n_ridges, q) float64: proj @ lam of every sample, O(q) a sample along a piece instead "
             "of O(n). threads=2 shares the ridges with a second thread, one at a time (the ridges are "
             "independent: same results). "
             "A ridge with the configuration, history and plate path of an earlier one gets that ridge's results "
             "(the same bits) without computing them. Returns (status, ridge, solves, events); on a failure "
             "(status != 0, of the first failing ridge) every ridge keeps the history it had before the call.");
    m.def("_contact_simd_path", [] { return std::string(tactile::contact_simd_path()); },
          "The variant the contact kernels run now, by simd_path()'s names: 'avx2+fma' or the base variant.");
}
