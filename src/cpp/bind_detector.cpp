// Bindings of the Jordan-MLP slip-detector kernel (jordan_mlp.hpp).
//
// _core.JordanMLPf32 / _core.JordanMLPf64: N instances of one network.
//   __init__(w1, b1, w2, b2, input_mean, input_gain, n_instances, activation="exact")
//   step(x)        x: (n_instances, n_inputs) -> (n_instances, 3) [y_slip, y_non, y_pred]
//   run(x)         x: (n_instances, n_inputs, n) -> (3, n_instances, n); GIL released
//   state          y_pred(t-1) per instance (get/set), reset()
//   simd_path, set_simd_path(name), activation, time_step_ns(n_iter, repeats)
// _core.MemoryJordanf32 / _core.MemoryJordanf64: the load-memory detector of one pad
//   (detector_memory.hpp): the load-integral and pad feature stage in front of the
//   Jordan kernel with 8 inputs. Same API on the 4 raw channels per ridge; state is
//   (y_pred (n_ridges,), load (n_ridges, 2)).
// _core.BankJordanf32 / _core.BankJordanf64: the filter-bank detector (detector_bank.hpp):
//   IIR low-passes of the rates, rate energy, load and peak load in front of the Jordan
//   kernel. Same API on the 4 raw channels per ridge; state is (y_pred (n_ridges,),
//   filter states (n_ridges, n_state)).
// _core.jordan_loss_grad: training loss and exact BPTT gradient (jordan_bptt.hpp).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <cmath>
#include <cstring>
#include <stdexcept>
#include <memory>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include "detector_bank.hpp"
#include "detector_memory.hpp"
#include "jordan_bptt.hpp"
#include "jordan_mlp.hpp"
#include "owner.hpp"
#include "simd.hpp"  // DenormalGuard, the code variants

namespace py = pybind11;
using tactile::detector::Activation;
using tactile::detector::JordanMLP;
using tactile::detector::MemoryJordan;
using tactile::detector::BankJordan;
namespace simd = tactile::simd;

namespace {

std::string shape_str(const py::array& a) {
    std::ostringstream s;
    s << "(";
    for (py::ssize_t k = 0; k < a.ndim(); ++k) s << (k ? ", " : "") << a.shape(k);
    if (a.ndim() == 1) s << ",";
    s << ")";
    return s.str();
}

// A code variant by name (simd::parse_isa's names), one this CPU can run now.
simd::Isa parse_path(const std::string& name) {
    simd::Isa isa;
    if (!simd::parse_isa(name, &isa))
        throw py::value_error("path must be '" + std::string(simd::isa_name(simd::Isa::baseline)) +
                              "' (or 'generic'), 'avx2+fma' or 'native', got '" + name + "'");
    if (!simd::isa_supported(isa))
        throw py::value_error("path '" + name + "' is not supported by this CPU or build" +
                              (simd::baseline_forced() && simd::cpu_isa() == isa
                                   ? std::string(", or while the kernels are held to the baseline "
                                                 "(tactile_mirror.kernels.use_baseline, TM_SIMD=baseline)")
                                   : std::string()));
    return isa;
}

Activation parse_activation(const std::string& name) {
    if (name == "exact") return Activation::exact;
    if (name == "fast") return Activation::fast;
    throw py::value_error("activation must be 'exact' or 'fast', got '" + name + "'");
}

// A C-contiguous float64 copy of a weight array with the expected shape.
py::array_t<double, py::array::c_style | py::array::forcecast> weight(const py::handle& obj, const char* name,
                                                                     std::initializer_list<py::ssize_t> shape) {
    py::array a = py::array::ensure(obj);
    if (!a) throw py::type_error(std::string(name) + " must be an array of real numbers");
    if (a.dtype().kind() != 'f' && a.dtype().kind() != 'i' && a.dtype().kind() != 'u')
        throw py::type_error(std::string(name) + " must be a real array, got dtype " +
                             std::string(py::str(a.dtype())));
    bool ok = a.ndim() == py::ssize_t(shape.size());
    if (ok) {
        py::ssize_t k = 0;
        for (py::ssize_t s : shape) ok = ok && a.shape(k++) == s;
    }
    if (!ok) {
        std::ostringstream m;
        m << name << " must have shape (";
        py::ssize_t k = 0;
        for (py::ssize_t s : shape) m << (k++ ? ", " : "") << s;
        m << (shape.size() == 1 ? ",)" : ")") << ", got " << shape_str(a);
        throw py::value_error(m.str());
    }
    auto c = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(a);
    const double* d = c.data();
    for (py::ssize_t k = 0; k < c.size(); ++k)
        if (!std::isfinite(d[k])) throw py::value_error(std::string(name) + " must be finite");
    return c;
}

template <typename T>
const char* dtype_name();
template <>
const char* dtype_name<float>() { return "float32"; }
template <>
const char* dtype_name<double>() { return "float64"; }

// dtype T in native byte order. By type number, not by object: a dtype unpickled or made by
// another module is an equal but distinct object (an unpickled float64 array was refused as
// "must have dtype float64, got float64").
template <typename T>
bool is_dtype(const py::dtype& d) {
    return d.num() == py::dtype::of<T>().num() && d.byteorder() != '>';
}

// Checks dtype exactly (no silent conversion in the real-time binding).
template <typename T>
py::array_t<T, py::array::c_style> input(const py::handle& obj, const char* name) {
    if (!py::isinstance<py::array>(obj)) throw py::type_error(std::string(name) + " must be a numpy array");
    py::array a = py::reinterpret_borrow<py::array>(obj);
    if (!is_dtype<T>(a.dtype()))
        throw py::type_error(std::string(name) + " must have dtype " + dtype_name<T>() + ", got " +
                             std::string(py::str(a.dtype())));
    return py::array_t<T, py::array::c_style>::ensure(a);  // copies only if not C-contiguous
}

template <typename T>
struct PyJordan {
    std::unique_ptr<JordanMLP<T>> k;
    int n_inst, n_in;
    tactile::OwnerFlag owner;  // one thread at a time (run() releases the GIL)
};

// Claim a kernel for the duration of a call, or raise.
class Claim {
public:
    explicit Claim(tactile::OwnerFlag& f) : c_(f) {
        if (!c_.owns()) throw std::runtime_error("this detector is being used by another thread");
    }

private:
    tactile::OwnerClaim c_;
};

// Non-finite features would come out as a confident number (the sigmoid clamps),
// so they are refused, naming the first one: x[r * sr + i * si + t * st].
template <typename T>
void throw_first_nonfinite(const T* x, std::ptrdiff_t n_inst, std::ptrdiff_t n_in, std::ptrdiff_t n,
                           std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st);

template <typename T>
void check_features(const T* x, std::ptrdiff_t n_inst, std::ptrdiff_t n_in, std::ptrdiff_t n, std::ptrdiff_t sr,
                    std::ptrdiff_t si, std::ptrdiff_t st) {
    // x * 0 is +-0 for a finite x and NaN for Inf or NaN, so a sum of them is NaN iff
    // some value is not finite. Contiguous rows go a vector (and four accumulators) at
    // a time: the per-value isfinite loop was not vectorised and cost about a sixth of
    // a float32 bank-net block run (measured 37 ns of 220 per tick of 6 ridges).
    typedef typename tactile::simd::Vec<T, tactile::simd::kBaseBytes>::type V;
    constexpr int NL = tactile::simd::Vec<T, tactile::simd::kBaseBytes>::lanes;
    V acc[4] = {};
    T sacc = 0;
    for (std::ptrdiff_t r = 0; r < n_inst; ++r)
        for (std::ptrdiff_t i = 0; i < n_in; ++i) {
            const T* row = x + r * sr + i * si;
            std::ptrdiff_t t = 0;
            if (st == 1)
                for (; t + 4 * NL <= n; t += 4 * NL)
                    for (int q = 0; q < 4; ++q) {
                        V v;
                        std::memcpy(&v, row + t + q * NL, sizeof v);
                        acc[q] += v * T(0);
                    }
            for (; t < n; ++t) sacc += row[t * st] * T(0);
        }
    const V a = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (int q = 0; q < NL; ++q) sacc += a[q];
    if (sacc == T(0)) return;
    throw_first_nonfinite(x, n_inst, n_in, n, sr, si, st);
}

// The ValueError for the earliest non-finite feature (by sample, then ridge, then
// channel); returns if there is none.
template <typename T>
void throw_first_nonfinite(const T* x, std::ptrdiff_t n_inst, std::ptrdiff_t n_in, std::ptrdiff_t n,
                           std::ptrdiff_t sr, std::ptrdiff_t si, std::ptrdiff_t st) {
    for (std::ptrdiff_t t = 0; t < n; ++t)
        for (std::ptrdiff_t r = 0; r < n_inst; ++r)
            for (std::ptrdiff_t i = 0; i < n_in; ++i) {
                const T v = x[r * sr + i * si + t * st];
                if (!std::isfinite(v))
                    throw py::value_error("features must be finite: ridge " + std::to_string(r) + ", channel " +
                                          std::to_string(i) + ", sample " + std::to_string(t) + " is " +
                                          std::string(py::str(py::float_(double(v)))));
            }
}

template <typename T>
void bind_one(py::module_& m, const char* cls) {
    using PJ = PyJordan<T>;
    py::class_<PJ>(m, cls,
                   (std::string("Jordan recurrent MLP slip-detector kernel (") + dtype_name<T>() +
                    "), n_instances instances sharing one weight set.")
                       .c_str())
        .def(py::init([](py::handle w1, py::handle b1, py::handle w2, py::handle b2, py::handle input_mean,
                         py::handle input_gain, int n_instances, const std::string& activation) {
                 py::array a1 = py::array::ensure(w1);
                 if (!a1 || a1.ndim() != 2 || a1.shape(1) < 2)
                     throw py::value_error("w1 must have shape (n_hidden, n_inputs + 1) with n_inputs >= 1");
                 const py::ssize_t h = a1.shape(0), nin = a1.shape(1) - 1;
                 if (h < 1 || h > 1024) throw py::value_error("w1 must have 1 to 1024 rows (n_hidden)");
                 if (nin > 64) throw py::value_error("w1 allows at most 64 inputs (65 columns)");
                 if (n_instances < 1 || n_instances > 65536)
                     throw py::value_error("n_instances must be in [1, 65536], got " + std::to_string(n_instances));
                 const Activation act = parse_activation(activation);
                 auto cw1 = weight(w1, "w1", {h, nin + 1});
                 auto cb1 = weight(b1, "b1", {h});
                 auto cw2 = weight(w2, "w2", {2, h});
                 auto cb2 = weight(b2, "b2", {2});
                 auto cm = weight(input_mean, "input_mean", {nin});
                 auto cg = weight(input_gain, "input_gain", {nin});
                 auto p = std::make_unique<PJ>();
                 p->k = std::make_unique<JordanMLP<T>>(int(nin), int(h), n_instances, cw1.data(), cb1.data(),
                                                       cw2.data(), cb2.data(), cm.data(), cg.data(), act);
                 p->n_inst = n_instances;
                 p->n_in = int(nin);
                 return p;
             }),
             py::arg("w1"), py::arg("b1"), py::arg("w2"), py::arg("b2"), py::arg("input_mean"),
             py::arg("input_gain"), py::arg("n_instances"), py::arg("activation") = "exact")
        .def_property_readonly("n_instances", [](const PJ& p) { return p.n_inst; })
        .def_property_readonly("n_inputs", [](const PJ& p) { return p.n_in; })
        .def_property_readonly("n_hidden", [](const PJ& p) { return p.k->n_hidden(); })
        .def_property_readonly("dtype", [](const PJ&) { return py::dtype::of<T>(); })
        .def_property(
            "activation",
            [](const PJ& p) { return std::string(p.k->activation() == Activation::exact ? "exact" : "fast"); },
            [](PJ& p, const std::string& a) {
                const Activation act = parse_activation(a);
                Claim claim(p.owner);
                p.k->set_activation(act);
            })
        .def_property_readonly("simd_path", [](const PJ& p) { return std::string(simd::isa_name(p.k->isa())); })
        .def(
            "set_simd_path",
            [](PJ& p, const std::string& name) {
                const auto isa = parse_path(name);
                Claim claim(p.owner);
                p.k->set_isa(isa);
            },
            py::arg("path"))
        .def_property(
            "state",
            [](PJ& p) {
                py::array_t<T> out(p.n_inst);
                Claim claim(p.owner);
                p.k->get_state(out.mutable_data());
                return out;
            },
            [](PJ& p, py::handle state) {
                auto s = input<T>(state, "state");
                if (s.ndim() != 1 || s.shape(0) != p.n_inst)
                    throw py::value_error("state must have shape (" + std::to_string(p.n_inst) + ",), got " +
                                          shape_str(s));
                for (py::ssize_t i = 0; i < s.size(); ++i)
                    if (!std::isfinite(s.data()[i])) throw py::value_error("state must be finite");
                Claim claim(p.owner);
                p.k->set_state(s.data());
            },
            "y_pred(t-1) of every instance (the Jordan feedback state).")
        .def(
            "reset",
            [](PJ& p) {
                Claim claim(p.owner);
                p.k->reset();
            },
            "Set the feedback state to zero.")
        .def(
            "step",
            [](PJ& p, py::handle x) {
                auto a = input<T>(x, "x");
                if (a.ndim() != 2 || a.shape(0) != p.n_inst || a.shape(1) != p.n_in)
                    throw py::value_error("x must have shape (" + std::to_string(p.n_inst) + ", " +
                                          std::to_string(p.n_in) + "), got " + shape_str(a));
                check_features(a.data(), p.n_inst, p.n_in, 1, p.n_in, 1, 1);
                py::array_t<T> out({py::ssize_t(p.n_inst), py::ssize_t(3)});
                Claim claim(p.owner);
                p.k->step(a.data(), out.mutable_data());
                return out;
            },
            py::arg("x"), "One tick. x: (n_instances, n_inputs) -> (n_instances, 3) [y_slip, y_non, y_pred].")
        .def(
            "step_one",
            [](PJ& p, int instance, py::handle x) {
                if (instance < 0 || instance >= p.n_inst)
                    throw py::value_error("instance must be in [0, " + std::to_string(p.n_inst) + "), got " +
                                          std::to_string(instance));
                auto a = input<T>(x, "x");
                if (a.ndim() != 1 || a.shape(0) != p.n_in)
                    throw py::value_error("x must have shape (" + std::to_string(p.n_in) + ",), got " +
                                          shape_str(a));
                check_features(a.data(), 1, p.n_in, 1, p.n_in, 1, 1);
                py::array_t<T> out(3);
                Claim claim(p.owner);
                p.k->step_one(instance, a.data(), out.mutable_data());
                return out;
            },
            py::arg("instance"), py::arg("x"),
            "One tick of one instance (scalar code). x: (n_inputs,) -> (3,) [y_slip, y_non, y_pred].")
        .def(
            "run",
            [](PJ& p, py::handle x, bool reset) {
                auto a = input<T>(x, "x");
                if (a.ndim() != 3 || a.shape(0) != p.n_inst || a.shape(1) != p.n_in)
                    throw py::value_error("x must have shape (" + std::to_string(p.n_inst) + ", " +
                                          std::to_string(p.n_in) + ", n), got " + shape_str(a));
                const py::ssize_t n = a.shape(2);
                py::array_t<T> out({py::ssize_t(3), py::ssize_t(p.n_inst), n});
                T* o = out.mutable_data();
                const T* xd = a.data();
                const std::ptrdiff_t N = p.n_inst, nin = p.n_in;
                check_features(xd, N, nin, n, nin * n, n, 1);
                {
                    Claim claim(p.owner);
                    py::gil_scoped_release release;
                    if (reset) p.k->reset();
                    tactile::DenormalGuard ftz;  // subnormal inputs cost ~60x otherwise
                    p.k->run(xd, nin * n, n, 1, n, o, o + N * n, o + 2 * N * n, n);
                }
                return out;
            },
            py::arg("x"), py::arg("reset") = false,
            "Run the recurrence over a block. x: (n_instances, n_inputs, n) -> (3, n_instances, n) "
            "[y_slip, y_non, y_pred]; the state carries over between calls (reset=True: starts from zero, "
            "in the same claim of the kernel). A NaN/Inf feature is a ValueError naming ridge, channel and "
            "sample, the state unchanged.")
        .def(
            "time_step_ns",
            [](PJ& p, long n_iter, int repeats, const std::string& mode) {
                if (n_iter < 1) throw py::value_error("n_iter must be >= 1");
                if (repeats < 1) throw py::value_error("repeats must be >= 1");
                if (mode != "simd" && mode != "scalar")
                    throw py::value_error("mode must be 'simd' or 'scalar', got '" + mode + "'");
                if (p.n_inst * p.n_in > 64 * 16) throw py::value_error("too many instances for the timing loop");
                Claim claim(p.owner);
                py::gil_scoped_release release;
                return p.k->time_step_ns(n_iter, repeats, mode == "scalar");
            },
            py::arg("n_iter") = 1000000, py::arg("repeats") = 5, py::arg("mode") = "simd",
            "Mean time of one tick of all instances over n_iter ticks, measured inside C++ (ns, best of "
            "repeats). mode='simd' times step() on the selected SIMD path; mode='scalar' times a plain "
            "scalar loop over the instances (step_one), the reference.");
}

// The state of a staged net (y_pred and its filter states) before a call, put back
// when the call leaves a non-finite filter state: finite features large enough
// (|x| near the type's maximum, times a leaky integral's gain of fs tau) overflow a
// filter, and an inf or NaN state never recovers (every later output would be one
// constant until reset()). Copies N (n_state + 1) values: small beside a call.
template <typename T, typename PM>
class StateUndo {
public:
    explicit StateUndo(PM& p)
        : yp_(static_cast<std::size_t>(p.n_r)), filt_(static_cast<std::size_t>(p.n_r * p.k->n_state())) {
        p.k->get_state(yp_.data(), filt_.data());
    }
    void restore(PM& p) const { p.k->set_state(yp_.data(), filt_.data()); }
    // Raise (state put back) if the call left a non-finite state.
    void refuse_overflow(PM& p) {
        std::vector<T> yp(yp_.size()), filt(filt_.size());
        p.k->get_state(yp.data(), filt.data());
        bool ok = true;
        for (T v : yp) ok &= std::isfinite(v);
        for (T v : filt) ok &= std::isfinite(v);
        if (ok) return;
        restore(p);
        throw py::value_error("features overflow the detector's filter states (finite values too large for " +
                              std::string(dtype_name<T>()) + " once filtered); the state is unchanged");
    }

private:
    std::vector<T> yp_, filt_;
};

// The sizes, dtype, SIMD path, state, reset, step, run and time_step_ns of a detector
// with a feature stage in front of its net (PyMemory, PyBank): the same calls, only the
// stage's constructor and its number of states per ridge (k->n_state()) differ.
// state_name names the stage's states in messages.
template <typename T, typename PM>
void def_staged_net_calls(py::class_<PM>& cls, const char* state_name, const char* state_doc, const char* reset_doc,
                          const char* timing_doc) {
    const std::string pair_msg = std::string("state must be a pair (y_pred, ") + state_name + ")";
    cls.def_property(
           "state",
           [](PM& p) {
               py::array_t<T> yp(p.n_r);
               py::array_t<T> ld({py::ssize_t(p.n_r), py::ssize_t(p.k->n_state())});
               Claim claim(p.owner);
               p.k->get_state(yp.mutable_data(), ld.mutable_data());
               return py::make_tuple(yp, ld);
           },
           [pair_msg](PM& p, py::tuple state) {
               if (state.size() != 2) throw py::value_error(pair_msg);
               auto yp = input<T>(state[0], "state[0]");
               auto ld = input<T>(state[1], "state[1]");
               if (yp.ndim() != 1 || yp.shape(0) != p.n_r)
                   throw py::value_error("state[0] must have shape (" + std::to_string(p.n_r) + ",), got " +
                                         shape_str(yp));
               if (ld.ndim() != 2 || ld.shape(0) != p.n_r || ld.shape(1) != p.k->n_state())
                   throw py::value_error("state[1] must have shape (" + std::to_string(p.n_r) + ", " +
                                         std::to_string(p.k->n_state()) + "), got " + shape_str(ld));
               for (py::ssize_t i = 0; i < yp.size(); ++i)
                   if (!std::isfinite(yp.data()[i])) throw py::value_error("state[0] must be finite");
               for (py::ssize_t i = 0; i < ld.size(); ++i)
                   if (!std::isfinite(ld.data()[i])) throw py::value_error("state[1] must be finite");
               Claim claim(p.owner);
               p.k->set_state(yp.data(), ld.data());
           },
           state_doc);
    cls
        .def_property_readonly("n_instances", [](const PM& p) { return p.n_r; })
        .def_property_readonly("n_inputs", [](const PM&) { return 4; })
        .def_property_readonly("n_hidden", [](const PM& p) { return p.k->n_hidden(); })
        .def_property_readonly("dtype", [](const PM&) { return py::dtype::of<T>(); })
        .def_property_readonly("simd_path",
                               [](const PM& p) { return std::string(simd::isa_name(p.k->net().isa())); })
        .def(
            "set_simd_path",
            [](PM& p, const std::string& name) {
                const auto isa = parse_path(name);
                Claim claim(p.owner);
                p.k->net().set_isa(isa);
            },
            py::arg("path"))
        .def(
            "reset",
            [](PM& p) {
                Claim claim(p.owner);
                p.k->reset();
            },
            reset_doc)
        .def(
            "step",
            [](PM& p, py::handle x) {
                auto a = input<T>(x, "x");
                if (a.ndim() != 2 || a.shape(0) != p.n_r || a.shape(1) != 4)
                    throw py::value_error("x must have shape (" + std::to_string(p.n_r) + ", 4), got " +
                                          shape_str(a));
                check_features(a.data(), p.n_r, 4, 1, 4, 1, 1);
                py::array_t<T> out({py::ssize_t(p.n_r), py::ssize_t(3)});
                Claim claim(p.owner);
                StateUndo<T, PM> undo(p);
                p.k->step(a.data(), out.mutable_data());
                undo.refuse_overflow(p);
                return out;
            },
            py::arg("x"),
            "One tick. x: (n_ridges, 4) -> (n_ridges, 3) [y_slip, y_non, y_pred]. NaN/Inf features, or finite "
            "ones so large that a filter state overflows: ValueError, state unchanged.")
        .def(
            "run",
            [](PM& p, py::handle x, bool reset) {
                auto a = input<T>(x, "x");
                if (a.ndim() != 3 || a.shape(0) != p.n_r || a.shape(1) != 4)
                    throw py::value_error("x must have shape (" + std::to_string(p.n_r) + ", 4, n), got " +
                                          shape_str(a));
                const py::ssize_t n = a.shape(2);
                py::array_t<T> out({py::ssize_t(3), py::ssize_t(p.n_r), n});
                T* o = out.mutable_data();
                const T* xd = a.data();
                const std::ptrdiff_t N = p.n_r;
                using Run = decltype(p.k->run(xd, 0, 0, 0, 0, o, o, o, 0));
                if constexpr (std::is_same<Run, bool>::value) {
                    // The kernel checks the inputs in its feature pass (BankJordan::run):
                    // on a non-finite one, the state of before the call is put back.
                    bool finite;
                    Claim claim(p.owner);
                    StateUndo<T, PM> undo(p);
                    {
                        py::gil_scoped_release release;
                        if (reset) p.k->reset();
                        tactile::DenormalGuard ftz;
                        finite = p.k->run(xd, 4 * n, n, 1, n, o, o + N * n, o + 2 * N * n, n);
                        if (!finite) undo.restore(p);
                    }
                    if (!finite) {
                        throw_first_nonfinite(xd, N, 4, n, 4 * n, n, 1);
                        // (all finite now: another thread rewrote x during the run)
                        throw py::value_error("features must be finite: x changed while the run read it");
                    }
                    undo.refuse_overflow(p);
                } else {
                    check_features(xd, N, 4, n, 4 * n, n, 1);
                    Claim claim(p.owner);
                    StateUndo<T, PM> undo(p);
                    {
                        py::gil_scoped_release release;
                        if (reset) p.k->reset();
                        tactile::DenormalGuard ftz;
                        p.k->run(xd, 4 * n, n, 1, n, o, o + N * n, o + 2 * N * n, n);
                    }
                    undo.refuse_overflow(p);
                }
                return out;
            },
            py::arg("x"), py::arg("reset") = false,
            "Run over a block. x: (n_ridges, 4, n) -> (3, n_ridges, n) [y_slip, y_non, y_pred]; the state "
            "carries over between calls (reset=True starts from zero). NaN/Inf features, or finite ones so "
            "large that a filter state overflows: ValueError, state unchanged.")
        .def(
            "time_step_ns",
            [](PM& p, long n_iter, int repeats) {
                if (n_iter < 1) throw py::value_error("n_iter must be >= 1");
                if (repeats < 1) throw py::value_error("repeats must be >= 1");
                if (p.n_r > 64) throw py::value_error("too many ridges for the timing loop");
                Claim claim(p.owner);
                py::gil_scoped_release release;
                return p.k->time_step_ns(n_iter, repeats);
            },
            py::arg("n_iter") = 1000000, py::arg("repeats") = 5,
            timing_doc);
}

template <typename T>
struct PyMemory {
    std::unique_ptr<MemoryJordan<T>> k;
    int n_r;
    tactile::OwnerFlag owner;
};

template <typename T>
void bind_memory(py::module_& m, const char* cls) {
    using PM = PyMemory<T>;
    constexpr int NF = MemoryJordan<T>::n_features;
    auto cls_ = py::class_<PM>(m, cls,
                   (std::string("Load-memory slip detector of one pad (") + dtype_name<T>() +
                    "): load integrals and pad channels in front of the Jordan kernel (8 inputs).")
                       .c_str())
        .def(py::init([](py::handle w1, py::handle b1, py::handle w2, py::handle b2, py::handle input_mean,
                         py::handle input_gain, int n_ridges, double fs, double tau, const std::string& activation) {
                 py::array a1 = py::array::ensure(w1);
                 if (!a1 || a1.ndim() != 2 || a1.shape(1) != NF + 1)
                     throw py::value_error("w1 must have shape (n_hidden, 9): 8 inputs and the feedback");
                 const py::ssize_t h = a1.shape(0);
                 if (h < 1 || h > 1024) throw py::value_error("w1 must have 1 to 1024 rows (n_hidden)");
                 if (n_ridges < 1 || n_ridges > 65536)
                     throw py::value_error("n_ridges must be in [1, 65536], got " + std::to_string(n_ridges));
                 if (!(std::isfinite(fs) && fs > 0)) throw py::value_error("fs must be a positive number of Hz");
                 if (!(std::isfinite(tau) && tau > 0)) throw py::value_error("tau must be a positive number of s");
                 const Activation act = parse_activation(activation);
                 auto cw1 = weight(w1, "w1", {h, NF + 1});
                 auto cb1 = weight(b1, "b1", {h});
                 auto cw2 = weight(w2, "w2", {2, h});
                 auto cb2 = weight(b2, "b2", {2});
                 auto cm = weight(input_mean, "input_mean", {NF});
                 auto cg = weight(input_gain, "input_gain", {NF});
                 auto p = std::make_unique<PM>();
                 p->k = std::make_unique<MemoryJordan<T>>(int(h), n_ridges, cw1.data(), cb1.data(), cw2.data(),
                                                          cb2.data(), cm.data(), cg.data(), fs, tau, act);
                 p->n_r = n_ridges;
                 return p;
             }),
             py::arg("w1"), py::arg("b1"), py::arg("w2"), py::arg("b2"), py::arg("input_mean"),
             py::arg("input_gain"), py::arg("n_ridges"), py::arg("fs"), py::arg("tau"),
             py::arg("activation") = "exact");
    def_staged_net_calls<T>(cls_, "load", "(y_pred(t-1) per ridge, [load, press] per ridge): the recurrent state.",
                            "Set the feedback and load state to zero.",
                            "Mean time of one tick (feature stage and net) of all ridges, measured inside C++ "
                            "(ns, best of repeats).");
}

template <typename T>
struct PyBank {
    std::unique_ptr<BankJordan<T>> k;
    int n_r;
    tactile::OwnerFlag owner;
};

template <typename T>
void bind_bank(py::module_& m, const char* cls) {
    using PM = PyBank<T>;
    auto cls_ = py::class_<PM>(m, cls,
                   (std::string("Filter-bank slip detector (") + dtype_name<T>() +
                    "): IIR filters over the stress rates in front of the Jordan kernel.")
                       .c_str())
        .def(py::init([](py::handle w1, py::handle b1, py::handle w2, py::handle b2, py::handle input_mean,
                         py::handle input_gain, int n_ridges, double fs, py::handle lp_taus, py::handle abs_taus,
                         double load_tau, double peak_tau, const std::string& activation, py::handle knee,
                         bool pad_mean) {
                 auto lp = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(lp_taus);
                 auto ab = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(abs_taus);
                 if (!lp || lp.ndim() != 1 || lp.shape(0) < 1 || lp.shape(0) > BankJordan<T>::kMaxTaus)
                     throw py::value_error("lp_taus must be a 1-d array of 1 to 8 time constants");
                 if (!ab || ab.ndim() != 1 || ab.shape(0) > BankJordan<T>::kMaxTaus)
                     throw py::value_error("abs_taus must be a 1-d array of 0 to 8 time constants");
                 for (py::ssize_t i = 0; i < lp.size(); ++i)
                     if (!(std::isfinite(lp.data()[i]) && lp.data()[i] > 0))
                         throw py::value_error("lp_taus must be positive numbers of s");
                 for (py::ssize_t i = 0; i < ab.size(); ++i)
                     if (!(std::isfinite(ab.data()[i]) && ab.data()[i] > 0))
                         throw py::value_error("abs_taus must be positive numbers of s");
                 const int n_lp = int(lp.shape(0)), n_abs = int(ab.shape(0));
                 const py::ssize_t NF = BankJordan<T>::input_count(n_lp, n_abs, pad_mean);
                 py::array a1 = py::array::ensure(w1);
                 if (!a1 || a1.ndim() != 2 || a1.shape(1) != NF + 1)
                     throw py::value_error("w1 must have shape (n_hidden, " + std::to_string(NF + 1) +
                                           "): the bank's " + std::to_string(NF) + " inputs" +
                                           (pad_mean ? " (with the pad's mean)" : "") + " and the feedback");
                 const py::ssize_t h = a1.shape(0);
                 if (h < 1 || h > 1024) throw py::value_error("w1 must have 1 to 1024 rows (n_hidden)");
                 if (n_ridges < 1 || n_ridges > 65536)
                     throw py::value_error("n_ridges must be in [1, 65536], got " + std::to_string(n_ridges));
                 if (!(std::isfinite(fs) && fs > 0)) throw py::value_error("fs must be a positive number of Hz");
                 if (!(std::isfinite(load_tau) && load_tau > 0))
                     throw py::value_error("load_tau must be a positive number of s");
                 if (!(std::isfinite(peak_tau) && peak_tau > 0))
                     throw py::value_error("peak_tau must be a positive number of s");
                 const Activation act = parse_activation(activation);
                 auto cw1 = weight(w1, "w1", {h, NF + 1});
                 auto cb1 = weight(b1, "b1", {h});
                 auto cw2 = weight(w2, "w2", {2, h});
                 auto cb2 = weight(b2, "b2", {2});
                 auto cm = weight(input_mean, "input_mean", {NF});
                 auto cg = weight(input_gain, "input_gain", {NF});
                 // (the kernel checks the knees' values: std::invalid_argument, a ValueError here)
                 py::array_t<double, py::array::c_style | py::array::forcecast> ck;
                 if (!knee.is_none()) ck = weight(knee, "knee", {NF});
                 auto p = std::make_unique<PM>();
                 p->k = std::make_unique<BankJordan<T>>(int(h), n_ridges, cw1.data(), cb1.data(), cw2.data(),
                                                        cb2.data(), cm.data(), cg.data(), fs, n_lp, lp.data(),
                                                        n_abs, ab.data(), load_tau, peak_tau, act,
                                                        knee.is_none() ? nullptr : ck.data(), pad_mean);
                 p->n_r = n_ridges;
                 return p;
             }),
             py::arg("w1"), py::arg("b1"), py::arg("w2"), py::arg("b2"), py::arg("input_mean"),
             py::arg("input_gain"), py::arg("n_ridges"), py::arg("fs"), py::arg("lp_taus"), py::arg("abs_taus"),
             py::arg("load_tau"), py::arg("peak_tau"), py::arg("activation") = "exact", py::arg("knee") = py::none(),
             py::arg("pad_mean") = false)
        .def_property_readonly("n_features", [](const PM& p) { return p.k->n_features(); })
        .def_property_readonly("net_inputs", [](const PM& p) { return p.k->n_inputs(); })
        .def_property_readonly("pad_mean", [](const PM& p) { return p.k->pad_mean(); })
        .def_property_readonly("compressed", [](const PM& p) { return p.k->compressed(); });
    def_staged_net_calls<T>(cls_, "filters",
                            "(y_pred(t-1) per ridge, filter states (n_ridges, n_state)): the recurrent state.",
                            "Set the feedback and filter states to zero.",
                            "Mean time of one tick (filter bank and net) of all ridges, measured inside C++ "
                            "(ns, best of repeats).");
}

}  // namespace

void tm_bind_detector(py::module_& m) {
    bind_one<float>(m, "JordanMLPf32");
    bind_one<double>(m, "JordanMLPf64");
    bind_memory<float>(m, "MemoryJordanf32");
    bind_memory<double>(m, "MemoryJordanf64");
    bind_bank<float>(m, "BankJordanf32");
    bind_bank<double>(m, "BankJordanf64");
    m.def(
        "detector_sigmoid",
        [](py::handle a, const std::string& activation, const std::string& path) {
            const Activation act = parse_activation(activation);
            const simd::Isa isa = parse_path(path);
            if (!py::isinstance<py::array>(a)) throw py::type_error("a must be a numpy array");
            py::array arr = py::reinterpret_borrow<py::array>(a);
            if (is_dtype<float>(arr.dtype())) {
                auto c = py::array_t<float, py::array::c_style>::ensure(arr);
                py::array_t<float> out(c.size());
                simd::sigmoid_array<float>(c.data(), out.mutable_data(), std::size_t(c.size()), act, isa);
                return py::array(out);
            }
            if (is_dtype<double>(arr.dtype())) {
                auto c = py::array_t<double, py::array::c_style>::ensure(arr);
                py::array_t<double> out(c.size());
                simd::sigmoid_array<double>(c.data(), out.mutable_data(), std::size_t(c.size()), act, isa);
                return py::array(out);
            }
            throw py::type_error("a must have dtype float32 or float64, got " + std::string(py::str(arr.dtype())));
        },
        py::arg("a"), py::arg("activation") = "fast", py::arg("path") = "avx2+fma",
        "The detector kernel's sigmoid (with its clamp) applied to a flat copy of a; for error measurements.");
    m.def(
        "jordan_loss_grad",
        [](py::handle theta, py::handle xn, py::handle t_slip, py::handle t_pred, py::handle w_slip,
           py::handle w_pred, py::handle length, int n_hidden, int n_threads) {
            auto th = input<double>(theta, "theta");
            auto x = input<double>(xn, "xn");
            if (x.ndim() != 3) throw py::value_error("xn must have shape (n_seq, n_inputs, n), got " + shape_str(x));
            const py::ssize_t S = x.shape(0), nin = x.shape(1), n = x.shape(2);
            if (nin < 1 || nin > 64) throw py::value_error("xn must have 1 to 64 inputs, got " + std::to_string(nin));
            if (n_hidden < 1 || n_hidden > 1024)
                throw py::value_error("n_hidden must be in [1, 1024], got " + std::to_string(n_hidden));
            if (n_threads < 1 || n_threads > 256)
                throw py::value_error("n_threads must be in [1, 256], got " + std::to_string(n_threads));
            const py::ssize_t n_par = py::ssize_t(n_hidden) * (nin + 1) + 3 * py::ssize_t(n_hidden) + 2;
            if (th.ndim() != 1 || th.shape(0) != n_par)
                throw py::value_error("theta must have shape (" + std::to_string(n_par) + ",), got " + shape_str(th));
            for (py::ssize_t k = 0; k < n_par; ++k)
                if (!std::isfinite(th.data()[k])) throw py::value_error("theta must be finite");
            py::array_t<double, py::array::c_style> seq[4] = {input<double>(t_slip, "t_slip"),
                                                              input<double>(t_pred, "t_pred"),
                                                              input<double>(w_slip, "w_slip"),
                                                              input<double>(w_pred, "w_pred")};
            const char* names[4] = {"t_slip", "t_pred", "w_slip", "w_pred"};
            for (int k = 0; k < 4; ++k)
                if (seq[k].ndim() != 2 || seq[k].shape(0) != S || seq[k].shape(1) != n)
                    throw py::value_error(std::string(names[k]) + " must have shape (" + std::to_string(S) + ", " +
                                          std::to_string(n) + "), got " + shape_str(seq[k]));
            py::array la = py::array::ensure(length);
            if (!la || (la.dtype().kind() != 'i' && la.dtype().kind() != 'u'))
                throw py::type_error("length must be an integer array");
            auto len = py::array_t<std::ptrdiff_t, py::array::c_style | py::array::forcecast>::ensure(la);
            if (len.ndim() != 1 || len.shape(0) != S)
                throw py::value_error("length must have shape (" + std::to_string(S) + ",), got " + shape_str(len));
            for (py::ssize_t k = 0; k < S; ++k)
                if (len.data()[k] < 0 || len.data()[k] > n)
                    throw py::value_error("length must be in [0, " + std::to_string(n) + "], got " +
                                          std::to_string(len.data()[k]) + " at " + std::to_string(k));
            tactile::detector::BpttProblem P;
            P.n_inputs = int(nin);
            P.n_hidden = n_hidden;
            P.n_seq = int(S);
            P.n = n;
            P.x = x.data();
            P.t_slip = seq[0].data();
            P.t_pred = seq[1].data();
            P.w_slip = seq[2].data();
            P.w_pred = seq[3].data();
            P.length = len.data();
            py::array_t<double> grad(n_par);
            double loss;
            {
                py::gil_scoped_release release;
                loss = tactile::detector::jordan_loss_grad(P, th.data(), grad.mutable_data(), n_threads);
            }
            return py::make_tuple(loss, grad);
        },
        py::arg("theta"), py::arg("xn"), py::arg("t_slip"), py::arg("t_pred"), py::arg("w_slip"), py::arg("w_pred"),
        py::arg("length"), py::arg("n_hidden"), py::arg("n_threads") = 1,
        "Weighted cross-entropy loss of the Jordan net and its exact BPTT gradient (float64, no weight decay): "
        "network.loss_and_grad in C++, each sequence run for its first length[s] samples. Returns (loss, grad).");
    m.def(
        "detector_cpu_has_avx2_fma", []() { return simd::isa_supported(simd::Isa::avx2_fma); },
        "True if the kernels' AVX2+FMA variant can run now: this CPU and build have one and the kernels are "
        "not held to the baseline.");
}
