// Bindings of the condensed contact solver (contact_solver.hpp).
//
// _core._ContactSolver(compliance, node_z, weights, r, w_tol)   one ridge
//   set_params(mu, mu_kinetic, tol, max_iter, max_active_set_iter)
//   step(plate_y, plate_z) -> (status, forces, displacement, state, slip_fraction, iterations)
//       status 0: the arrays are new copies of the result; else they are None and
//       error() gives (info, residual, tolerance)
//   error(), reset(), get_history(), set_history(...)
// _core._ContactPad(solvers)   several ridges stepped in one call, without the GIL
//   step(plate_y, plate_z[n_ridges]) -> (status, ridge, iterations, forces, displacement,
//       state, slip_fraction); the ridges are committed only if every one converged.
//   run(plate_y[T], plate_z[T, n_ridges], forces, displacement, state, slip_fraction,
//       iterations) -> (status, ridge, steps): a whole open-loop trajectory in one call
//       without the GIL, written into preallocated arrays (no allocation per step).
// _contact_simd_path(), _contact_set_baseline(on): the kernel variant (AVX2+FMA or
//   baseline) and a switch to force the baseline.
// The Python-facing classes are tactile_mirror.contact.ContactSolver and Pad, which
// validate arguments and turn a status into the reference implementation's exceptions.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <atomic>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "contact_solver.hpp"

namespace py = pybind11;
using tactile::ContactSolverKernel;
using tactile::ContactStatus;

namespace {

using F64 = py::array_t<double, py::array::c_style | py::array::forcecast>;
using I8 = py::array_t<std::int8_t, py::array::c_style>;

struct PyContact {
    ContactSolverKernel k;
    std::atomic<bool> busy{false};  // one call at a time: the pad steps without the GIL
    template <typename... A>
    explicit PyContact(A&&... a) : k(std::forward<A>(a)...) {}
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
        .def_property_readonly("factorizations", [](const PyContact& c) { return c.k.factorizations(); },
                               "piece LU factorisations since construction")
        .def_property_readonly("affine_steps", [](const PyContact& c) { return c.k.affine_steps(); },
                               "piece solves served by the affine response of an unchanged piece")
        .def_property_readonly("updates", [](const PyContact& c) { return c.k.updates(); },
                               "pieces solved by bordering the factored base piece instead of refactoring")
        .def("set_params",
             [](PyContact& c, double mu, double mu_kinetic, double tol, int max_iter, int max_as) {
                 Busy b(c);
                 c.k.params = {mu, mu_kinetic, tol, max_iter, max_as};
             },
             py::arg("mu"), py::arg("mu_kinetic"), py::arg("tol"), py::arg("max_iter"),
             py::arg("max_active_set_iter"))
        .def("step",
             [](PyContact& c, double plate_y, double plate_z) -> py::tuple {
                 Busy b(c);
                 const ContactStatus s = c.k.step(plate_y, plate_z);
                 if (s != ContactStatus::ok)
                     return py::make_tuple(static_cast<int>(s), py::none(), py::none(), py::none(), 0.0, 0);
                 const std::size_t n = c.k.n_nodes();
                 return py::make_tuple(0, copy_out(c.k.forces(), 2 * n), copy_out(c.k.displacement(), 2 * n),
                                       copy_out8(c.k.reported_state(), n), c.k.slip_fraction(), c.k.iterations());
             },
             py::arg("plate_y"), py::arg("plate_z"))
        .def("error",
             [](const PyContact& c) {
                 return py::make_tuple(c.k.error_info(), c.k.error_residual(), c.k.error_tolerance());
             },
             "(info, residual, tolerance) of the last failed step")
        .def("reset",
             [](PyContact& c) {
                 Busy b(c);
                 c.k.reset();
             })
        .def("get_history",
             [](const PyContact& c) {
                 const std::size_t n = c.k.n_nodes();
                 py::array_t<bool> sliding(static_cast<py::ssize_t>(n));
                 for (std::size_t i = 0; i < n; ++i) sliding.mutable_data()[i] = c.k.sliding()[i] != 0;
                 py::dict d;
                 d["lam"] = copy_out(c.k.lam(), 2 * n);
                 d["uy_prev"] = copy_out(c.k.uy_prev(), n);
                 d["s_prev"] = c.k.s_prev();
                 d["state"] = copy_out8(c.k.state(), n);
                 d["sign"] = copy_out(c.k.sign(), n);
                 d["sliding"] = sliding;
                 return d;
             })
        .def("set_history",
             [](PyContact& c, py::handle lam, py::handle uy_prev, double s_prev, py::handle state, py::handle sign,
                py::handle sliding) {
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
                 Busy b(c);
                 c.k.set_history(l.data(), u.data(), sg.data(), st.data(), sl.data(), s_prev);
             },
             py::arg("lam"), py::arg("uy_prev"), py::arg("s_prev"), py::arg("state"), py::arg("sign"),
             py::arg("sliding"));

    struct PyContactPad {
        std::vector<std::shared_ptr<PyContact>> ridges;
        std::size_t n = 0;
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
                 return p;
             }),
             py::arg("solvers"))
        .def_property_readonly("n_ridges", [](const PyContactPad& p) { return p.ridges.size(); })
        .def("step",
             [](PyContactPad& p, double plate_y, py::handle plate_z) -> py::tuple {
                 const std::size_t R = p.ridges.size(), n = p.n;
                 F64 z = vector_arg(plate_z, R, "plate_z");
                 std::vector<Busy> locks;
                 locks.reserve(R);
                 for (auto& r : p.ridges) locks.emplace_back(*r);
                 py::array_t<double> forces({static_cast<py::ssize_t>(R), static_cast<py::ssize_t>(2 * n)});
                 py::array_t<double> disp({static_cast<py::ssize_t>(R), static_cast<py::ssize_t>(2 * n)});
                 py::array_t<std::int8_t> state({static_cast<py::ssize_t>(R), static_cast<py::ssize_t>(n)});
                 py::array_t<double> frac(static_cast<py::ssize_t>(R));
                 double* fo = forces.mutable_data();
                 double* dout = disp.mutable_data();
                 std::int8_t* so = state.mutable_data();
                 double* fr = frac.mutable_data();
                 const double* zp = z.data();
                 ContactStatus status = ContactStatus::ok;
                 std::size_t bad = 0;
                 long its = 0;
                 {
                     py::gil_scoped_release nogil;
                     for (std::size_t k = 0; k < R && status == ContactStatus::ok; ++k) {
                         status = p.ridges[k]->k.solve(plate_y, zp[k]);
                         bad = k;
                     }
                     if (status == ContactStatus::ok) {
                         for (std::size_t k = 0; k < R; ++k) {
                             ContactSolverKernel& s = p.ridges[k]->k;
                             s.commit();
                             std::memcpy(fo + k * 2 * n, s.forces(), 2 * n * sizeof(double));
                             std::memcpy(dout + k * 2 * n, s.displacement(), 2 * n * sizeof(double));
                             std::memcpy(so + k * n, s.reported_state(), n);
                             fr[k] = s.slip_fraction();
                             its += s.iterations();
                         }
                     }
                 }
                 if (status != ContactStatus::ok)
                     return py::make_tuple(static_cast<int>(status), bad, 0, py::none(), py::none(), py::none(),
                                           py::none());
                 return py::make_tuple(0, 0, its, forces, disp, state, frac);
             },
             py::arg("plate_y"), py::arg("plate_z"))
        .def("run",
             [](PyContactPad& p, py::handle plate_y, py::handle plate_z, py::handle forces, py::handle disp,
                py::handle state, py::handle frac, py::handle iterations) -> py::tuple {
                 const std::size_t R = p.ridges.size(), n = p.n;
                 F64 y = F64::ensure(plate_y);
                 if (!y || y.ndim() != 1) throw py::value_error("plate_y must be a 1-D array");
                 const std::size_t T = static_cast<std::size_t>(y.shape(0));
                 F64 z = F64::ensure(plate_z);
                 if (!z || z.ndim() != 2 || static_cast<std::size_t>(z.shape(0)) != T ||
                     static_cast<std::size_t>(z.shape(1)) != R)
                     throw py::value_error("plate_z must have shape (" + std::to_string(T) + ", " +
                                           std::to_string(R) + ")");
                 auto out = [&](py::handle h, const char* name, std::size_t per_step, auto tag) {
                     using A = py::array_t<decltype(tag), py::array::c_style>;
                     if (!py::isinstance<py::array_t<decltype(tag)>>(h))
                         throw py::type_error(std::string(name) + " must be a numpy array of dtype " +
                                              std::string(py::str(py::dtype::of<decltype(tag)>())));
                     const py::array g = py::reinterpret_borrow<py::array>(h);
                     if (!g.writeable() || static_cast<std::size_t>(g.size()) != T * per_step ||
                         !(g.flags() & py::array::c_style) || g.ndim() < 1 ||
                         g.shape(0) != static_cast<py::ssize_t>(T))
                         throw py::value_error(std::string(name) + " must be a writeable C-contiguous array of " +
                                               std::to_string(T) + " x " + std::to_string(per_step) + " entries");
                     return py::reinterpret_borrow<A>(h);
                 };
                 auto fo = out(forces, "forces", R * 2 * n, double{});
                 const bool want_disp = !disp.is_none();
                 py::array_t<double, py::array::c_style> dis;
                 if (want_disp) dis = out(disp, "displacement", R * 2 * n, double{});
                 auto so = out(state, "state", R * n, std::int8_t{});
                 auto fr = out(frac, "slip_fraction", R, double{});
                 auto io = out(iterations, "iterations", 1, std::int32_t{});
                 std::vector<Busy> locks;
                 locks.reserve(R);
                 for (auto& r : p.ridges) locks.emplace_back(*r);
                 const double* yp = y.data();
                 const double* zp = z.data();
                 double* fop = fo.mutable_data();
                 double* dop = want_disp ? dis.mutable_data() : nullptr;
                 std::int8_t* sop = so.mutable_data();
                 double* frp = fr.mutable_data();
                 std::int32_t* iop = io.mutable_data();
                 ContactStatus status = ContactStatus::ok;
                 std::size_t bad = 0, done = 0;
                 {
                     py::gil_scoped_release nogil;
                     for (std::size_t t = 0; t < T; ++t) {
                         for (std::size_t k = 0; k < R && status == ContactStatus::ok; ++k) {
                             status = p.ridges[k]->k.solve(yp[t], zp[t * R + k]);
                             bad = k;
                         }
                         if (status != ContactStatus::ok) break;
                         long its = 0;
                         for (std::size_t k = 0; k < R; ++k) {
                             ContactSolverKernel& s = p.ridges[k]->k;
                             s.commit();
                             const std::size_t o = t * R + k;
                             std::memcpy(fop + o * 2 * n, s.forces(), 2 * n * sizeof(double));
                             if (dop) std::memcpy(dop + o * 2 * n, s.displacement(), 2 * n * sizeof(double));
                             std::memcpy(sop + o * n, s.reported_state(), n);
                             frp[o] = s.slip_fraction();
                             its += s.iterations();
                         }
                         iop[t] = static_cast<std::int32_t>(its);
                         done = t + 1;
                     }
                 }
                 return py::make_tuple(static_cast<int>(status), bad, done);
             },
             py::arg("plate_y"), py::arg("plate_z"), py::arg("forces"), py::arg("displacement"), py::arg("state"),
             py::arg("slip_fraction"), py::arg("iterations"),
             "Step every ridge through a whole trajectory without the GIL, into preallocated C-contiguous "
             "arrays: forces and displacement (T, n_ridges, 2n) float64 (displacement may be None), state "
             "(T, n_ridges, n) int8, slip_fraction (T, n_ridges) float64, iterations (T,) int32. Returns "
             "(status, ridge, steps): the steps done; on a failure (status != 0) at step `steps`, the ridges "
             "hold the history after the last good step.");
    m.def("_contact_simd_path", [] { return std::string(tactile::contact_simd_path()); },
          "The variant the contact kernels run, by simd_path()'s names: 'avx2+fma' or the base variant.");
    m.def("_contact_set_baseline", [](bool on) { tactile::set_contact_baseline(on); }, py::arg("on"),
          "Run the baseline contact kernels even on AVX2 hardware (for tests and benchmarks).");
}
