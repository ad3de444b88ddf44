// Bindings of the real-time pipeline (pipeline.hpp).
//
// _core._MirrorPipelineF64 / _MirrorPipelineF32 / _MirrorPipelineF64F32 (arithmetic of
// the filters and of the detector; inputs and outputs are float64 either way):
//   __init__(n_ridges, fs, use_u, sos_v, sos_u, sos_diff, v_limit, u_limit, w1, b1, w2, b2,
//            input_mean, input_gain, weights_fs, activation, slip_threshold, max_hold_ticks,
//            controller, shear_weights=None, bank=None, force_input=False, force_limit=100.0)
//   force_input: one more input after the voltages, the pad's tangential force (N), which
//   then drives the controller's shear signal instead of the strips (pipeline.hpp)
//   bank: None (the paper's net, w1 (H, 5)) or the filter-bank net's time constants
//   {"lp_taus", "abs_taus", "load_tau", "peak_tau"} (w1 (H, nf + 1), nf of them)
//   step(x, out=None) -> x_cmd     one tick; x float64 (n_inputs,), out float64 (n_outputs,)
//   process_block(x, features=False, accepted=False)
//   outputs (live read-only view), features, status, reset(x0), set_position(x),
//   controller_state, time_step_ns(n_iter, repeats)
// The Python-facing class is tactile_mirror.MirrorPipeline (pipeline.py).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <memory>
#include <string>
#include <vector>

#include "owner.hpp"
#include "pipeline.hpp"

namespace py = pybind11;
using tactile::ControllerKind;
using tactile::ControllerParams;
using tactile::MirrorPipeline;
using tactile::PipelineConfig;

namespace {

using F64 = py::array_t<double, py::array::c_style | py::array::forcecast>;

F64 real_array(const py::handle& obj, const char* name) {
    py::array a = py::array::ensure(obj);
    if (!a) throw py::type_error(std::string(name) + " must be an array of real numbers");
    const char k = a.dtype().kind();
    // (bool is refused as the tick's step() refuses it: True is not a voltage)
    if (k != 'f' && k != 'i' && k != 'u')
        throw py::type_error(std::string(name) + " must hold real numbers, got dtype " +
                             std::string(py::str(a.dtype())));
    return F64::ensure(a);
}

// sos argument: None or (n, 6).
F64 sos_array(const py::handle& obj, const char* name, int* n) {
    *n = 0;
    if (obj.is_none()) return F64();
    F64 a = real_array(obj, name);
    if (a.ndim() != 2 || a.shape(1) != 6)
        throw py::value_error(std::string(name) + " must have shape (n_sections, 6) or be None");
    *n = int(a.shape(0));
    return a;
}

F64 sized(const py::handle& obj, const char* name, std::vector<py::ssize_t> shape) {
    F64 a = real_array(obj, name);
    bool ok = a.ndim() == py::ssize_t(shape.size());
    for (std::size_t i = 0; ok && i < shape.size(); ++i) ok = a.shape(py::ssize_t(i)) == shape[i];
    if (!ok) {
        std::string s = "(";
        for (std::size_t i = 0; i < shape.size(); ++i) s += (i ? ", " : "") + std::to_string(shape[i]);
        s += shape.size() == 1 ? ",)" : ")";
        throw py::value_error(std::string(name) + " must have shape " + s);
    }
    return a;
}

ControllerKind kind_from(const std::string& v) {
    if (v == "none") return ControllerKind::none;
    if (v == "paper") return ControllerKind::paper;
    if (v == "velocity") return ControllerKind::velocity;
    throw py::value_error("controller.kind must be 'none', 'paper' or 'velocity', got '" + v + "'");
}

// The parameters come from the one list in controller.hpp (TM_CONTROLLER_FIELDS).
ControllerParams controller_from(const py::dict& d) {
    ControllerParams p;
    std::size_t nf = 0;
    const tactile::ControllerField* fields = tactile::controller_fields(&nf);
    for (auto item : d) {
        const std::string k = py::str(item.first);
        if (k == "kind") {
            p.kind = kind_from(py::str(item.second));
            continue;
        }
        std::size_t i = 0;
        while (i < nf && k != fields[i].name) ++i;
        if (i == nf) throw py::value_error("controller has no parameter '" + k + "'");
        p.*(fields[i].member) = py::cast<double>(item.second);
    }
    return p;
}

py::dict controller_dict(const ControllerParams& p) {
    py::dict d;
    d["kind"] = tactile::controller_name(p.kind);
    std::size_t nf = 0;
    const tactile::ControllerField* fields = tactile::controller_fields(&nf);
    for (std::size_t i = 0; i < nf; ++i) d[fields[i].name] = p.*(fields[i].member);
    return d;
}

// A 1-D float64 C-contiguous aligned array of length n (no conversion: the tick
// path must not copy). Returns its data pointer or throws naming the argument.
template <bool Writable>
auto fast_vector(const py::handle& h, std::size_t n, const char* name) {
    using P = typename std::conditional<Writable, double*, const double*>::type;
    const auto& api = py::detail::npy_api::get();
    if (!api.PyArray_Check_(h.ptr())) throw py::type_error(std::string(name) + " must be a numpy array");
    auto* a = py::detail::array_proxy(h.ptr());
    auto* d = py::detail::array_descriptor_proxy(a->descr);
    constexpr int need = py::detail::npy_api::NPY_ARRAY_C_CONTIGUOUS_ | py::detail::npy_api::NPY_ARRAY_ALIGNED_ |
                         (Writable ? py::detail::npy_api::NPY_ARRAY_WRITEABLE_ : 0);
    if (d->type_num != py::detail::npy_api::NPY_DOUBLE_ || d->byteorder == '>')
        throw py::type_error(std::string(name) + " must have dtype float64");
    if (a->nd != 1 || std::size_t(a->dimensions[0]) != n)
        throw py::value_error(std::string(name) + " must have shape (" + std::to_string(n) + ",)");
    if ((a->flags & need) != need)
        throw py::value_error(std::string(name) + (Writable ? " must be contiguous and writeable" : " must be contiguous"));
    return reinterpret_cast<P>(a->data);
}

py::dict status_dict(const tactile::PipelineStatus& s) {
    py::dict d;
    d["ticks"] = s.ticks;
    d["rejected"] = s.rejected;
    d["nonfinite"] = s.nonfinite;
    d["out_of_range"] = s.out_of_range;
    d["overflow"] = s.overflow;
    d["last_bad_tick"] = s.last_bad_tick;
    d["last_bad_channel"] = s.last_bad_channel;
    d["consecutive_rejected"] = s.consecutive_rejected;
    d["fault"] = s.fault;
    d["slip"] = s.slip;
    d["at_limit"] = s.at_limit;
    d["last_reason"] = tactile::reject_reason_name(s.last_reason);
    return d;
}

template <typename T, typename TD>
struct PyPipeline {
    std::unique_ptr<MirrorPipeline<T, TD>> p;
    std::atomic<bool> last_ok{true};
    tactile::OwnerFlag owner;  // one thread at a time (process_block runs without the GIL)
};

// Claim a pipeline for the duration of a call, or raise.
class Claim {
public:
    explicit Claim(tactile::OwnerFlag& f) : c_(f) {
        if (!c_.owns())
            throw std::runtime_error("this MirrorPipeline is being used by another thread (one thread at a time "
                                     "steps a pipeline; status may be read from any thread)");
    }

private:
    tactile::OwnerClaim c_;
};

double finite_position(double x, const char* name) {
    if (!std::isfinite(x)) throw py::value_error(std::string(name) + " must be a finite position in m, got " +
                                                 std::string(py::str(py::float_(x))));
    return x;
}

template <typename T, typename TD>
void bind_one(py::module_& m, const char* cls) {
    using PP = PyPipeline<T, TD>;
    py::class_<PP>(m, cls, "Real-time tactile-mirror pipeline (see tactile_mirror.MirrorPipeline).")
        .def(py::init([](int n_ridges, double fs, bool use_u, py::handle sos_v, py::handle sos_u,
                         py::handle sos_diff, double v_limit, double u_limit, py::handle w1, py::handle b1,
                         py::handle w2, py::handle b2, py::handle input_mean, py::handle input_gain,
                         double weights_fs, const std::string& activation, double slip_threshold,
                         long max_hold_ticks, py::dict controller, py::handle shear_weights, py::handle bank,
                         bool force_input, double force_limit) {
                 PipelineConfig c;
                 c.n_ridges = n_ridges;
                 c.fs = fs;
                 c.use_u = use_u;
                 F64 sv = sos_array(sos_v, "sos_v", &c.n_sos_v);
                 F64 su = sos_array(sos_u, "sos_u", &c.n_sos_u);
                 F64 sd = sos_array(sos_diff, "sos_diff", &c.n_sos_diff);
                 c.sos_v = c.n_sos_v ? sv.data() : nullptr;
                 c.sos_u = c.n_sos_u ? su.data() : nullptr;
                 c.sos_diff = c.n_sos_diff ? sd.data() : nullptr;
                 c.v_limit = v_limit;
                 c.u_limit = u_limit;
                 F64 lp, ab, kn;
                 if (!bank.is_none()) {
                     if (!py::isinstance<py::dict>(bank))
                         throw py::type_error("bank must be None or a dict of the filter bank's time constants");
                     py::dict b = bank.cast<py::dict>();
                     for (const char* k : {"lp_taus", "abs_taus", "load_tau", "peak_tau"})
                         if (!b.contains(k)) throw py::value_error(std::string("bank lacks '") + k + "'");
                     lp = real_array(b["lp_taus"], "bank['lp_taus']");
                     ab = real_array(b["abs_taus"], "bank['abs_taus']");
                     if (lp.ndim() != 1 || ab.ndim() != 1)
                         throw py::value_error("bank['lp_taus'] and bank['abs_taus'] must be 1-d");
                     c.detector_kind = 1;
                     c.bank_n_lp = int(lp.shape(0));
                     c.bank_lp_taus = lp.data();
                     c.bank_n_abs = int(ab.shape(0));
                     c.bank_abs_taus = ab.shape(0) ? ab.data() : nullptr;
                     c.bank_load_tau = b["load_tau"].cast<double>();
                     c.bank_peak_tau = b["peak_tau"].cast<double>();
                     if (b.contains("pad_mean") && !b["pad_mean"].is_none()) {  // None: absent, as bank_config
                         py::object pm = b["pad_mean"];
                         if (!py::isinstance<py::bool_>(pm) &&
                             !py::isinstance(pm, py::module_::import("numpy").attr("bool_")))
                             throw py::value_error("bank['pad_mean'] must be True or False");
                         c.bank_pad_mean = pm.cast<bool>() ? 1 : 0;
                     }
                     if (b.contains("knee") && !b["knee"].is_none()) {
                         kn = real_array(b["knee"], "bank['knee']");
                         const auto nk = tactile::detector::BankJordan<double>::input_count(c.bank_n_lp, c.bank_n_abs,
                                                                                            c.bank_pad_mean == 1);
                         if (kn.ndim() != 1 || kn.shape(0) != nk)
                             throw py::value_error("bank['knee'] must hold " + std::to_string(nk) +
                                                   " numbers, one per detector input");
                         c.bank_knee = kn.data();
                     }
                     if (c.bank_n_lp < 1 || c.bank_n_lp > 8 || c.bank_n_abs > 8)
                         throw py::value_error("bank: lp_taus must hold 1 to 8 and abs_taus 0 to 8 time constants");
                 }
                 const py::ssize_t nf = tactile::detector_input_count(c);
                 F64 aw1 = real_array(w1, "w1");
                 if (aw1.ndim() != 2 || aw1.shape(1) != nf + 1)
                     throw py::value_error("w1 must have shape (n_hidden, " + std::to_string(nf + 1) + "): " +
                                           std::to_string(nf) + " detector inputs and the y_pred feedback");
                 const py::ssize_t h = aw1.shape(0);
                 c.n_hidden = int(h);
                 F64 ab1 = sized(b1, "b1", {h}), aw2 = sized(w2, "w2", {2, h}), ab2 = sized(b2, "b2", {2});
                 F64 am = sized(input_mean, "input_mean", {nf}), ag = sized(input_gain, "input_gain", {nf});
                 c.w1 = aw1.data();
                 c.b1 = ab1.data();
                 c.w2 = aw2.data();
                 c.b2 = ab2.data();
                 c.input_mean = am.data();
                 c.input_gain = ag.data();
                 c.weights_fs = weights_fs;
                 if (activation == "exact")
                     c.activation = 0;
                 else if (activation == "fast")
                     c.activation = 1;
                 else
                     throw py::value_error("activation must be 'exact' or 'fast', got '" + activation + "'");
                 c.slip_threshold = slip_threshold;
                 c.max_hold_ticks = max_hold_ticks;
                 F64 asw;
                 if (!shear_weights.is_none()) {
                     asw = sized(shear_weights, "shear_weights", {py::ssize_t(n_ridges), 2});
                     c.shear_weights = asw.data();
                 }
                 c.controller = controller_from(controller);
                 c.force_input = force_input ? 1 : 0;
                 c.force_limit = force_limit;
                 auto pp = std::make_unique<PP>();
                 try {
                     pp->p = std::make_unique<MirrorPipeline<T, TD>>(c);
                 } catch (const std::invalid_argument& e) {
                     throw py::value_error(e.what());
                 }
                 return pp;
             }),
             py::arg("n_ridges"), py::arg("fs"), py::arg("use_u"), py::arg("sos_v"), py::arg("sos_u"),
             py::arg("sos_diff"), py::arg("v_limit"), py::arg("u_limit"), py::arg("w1"), py::arg("b1"),
             py::arg("w2"), py::arg("b2"), py::arg("input_mean"), py::arg("input_gain"), py::arg("weights_fs"),
             py::arg("activation"), py::arg("slip_threshold"), py::arg("max_hold_ticks"), py::arg("controller"),
             py::arg("shear_weights") = py::none(), py::arg("bank") = py::none(), py::arg("force_input") = false,
             py::arg("force_limit") = 100.0)
        .def_property_readonly("n_ridges", [](const PP& s) { return s.p->n_ridges(); })
        .def_property_readonly("n_inputs", [](const PP& s) { return s.p->n_inputs(); })
        .def_property_readonly("n_outputs", [](const PP& s) { return s.p->n_outputs(); })
        .def_property_readonly("fs", [](const PP& s) { return s.p->fs(); })
        .def_property_readonly("use_u", [](const PP& s) { return s.p->use_u(); })
        .def_property_readonly("force_input", [](const PP& s) { return s.p->force_input(); })
        .def_property_readonly("detector_kind", [](const PP& s) { return s.p->detector_kind(); })
        .def_property_readonly("n_detector_inputs", [](const PP& s) { return s.p->n_detector_inputs(); })
        .def_property_readonly("dtype", [](const PP&) { return py::dtype::of<T>(); })
        .def_property_readonly("detector_dtype", [](const PP&) { return py::dtype::of<TD>(); })
        .def_property_readonly("simd_path", [](const PP& s) {
            return std::string("filters ") + tactile::simd::isa_name(s.p->filter_isa()) + ", detector " +
                   s.p->simd_path();
        })
        .def_property_readonly("controller", [](const PP& s) { return controller_dict(s.p->controller().params()); })
        .def(
            "step",
            [](PP& s, py::handle x, py::handle out) {
                const double* xp = fast_vector<false>(x, s.p->n_inputs(), "x");
                double* op = out.is_none() ? nullptr : fast_vector<true>(out, s.p->n_outputs(), "out");
                Claim claim(s.owner);
                s.last_ok = s.p->step(xp, op);
                return s.p->last_output()[0];
            },
            py::arg("x"), py::arg("out") = py::none(),
            "One tick. x: float64 (n_inputs,) C-contiguous, no conversion; out: float64 (n_outputs,) receives "
            "[x_cmd, v_cmd, y_slip_0, y_non_0, y_pred_0, ...]. Returns x_cmd (m). A NaN/Inf or out-of-range "
            "sample rejects the tick (counted in status; detector outputs held).")
        .def(
            "process_block",
            [](PP& s, py::handle x, bool features, bool accepted) {
                F64 a = real_array(x, "x");
                const std::size_t ni = s.p->n_inputs(), no = s.p->n_outputs(), nf = s.p->n_features();
                if (a.ndim() != 2 || std::size_t(a.shape(1)) != ni)
                    throw py::value_error("x must have shape (n_ticks, " + std::to_string(ni) + ")");
                const std::size_t n = std::size_t(a.shape(0));
                py::array_t<double> out({py::ssize_t(n), py::ssize_t(no)});
                py::array_t<double> f;
                py::array_t<bool> acc;
                double* fp = nullptr;
                std::uint8_t* ap = nullptr;
                if (features) {
                    f = py::array_t<double>({py::ssize_t(n), py::ssize_t(s.p->n_ridges()), py::ssize_t(4)});
                    fp = f.mutable_data();
                }
                if (accepted) {
                    acc = py::array_t<bool>(py::ssize_t(n));
                    ap = reinterpret_cast<std::uint8_t*>(acc.mutable_data());
                }
                const double* xp = a.data();
                double* op = out.mutable_data();
                {
                    Claim claim(s.owner);
                    py::gil_scoped_release release;
                    s.p->process_block(xp, n, ni, op, no, fp, nf, ap);
                    if (n) s.last_ok = ap ? bool(ap[n - 1]) : s.p->status().consecutive_rejected == 0;
                }
                py::tuple r(1 + int(features) + int(accepted));
                int k = 0;
                r[k++] = out;
                if (features) r[k++] = f;
                if (accepted) r[k++] = acc;
                return r;
            },
            py::arg("x"), py::arg("features") = false, py::arg("accepted") = false,
            "n ticks, exactly n calls of step(): x (n, n_inputs) -> (out (n, n_outputs)[, features (n, n_ridges, 4)]"
            "[, accepted (n,) bool]). The GIL is released.")
        .def_property_readonly("outputs",
                               [](py::object self) {
                                   PP& s = self.cast<PP&>();
                                   py::array_t<double> v({py::ssize_t(s.p->n_outputs())}, {py::ssize_t(8)},
                                                         s.p->last_output(), self);
                                   py::detail::array_proxy(v.ptr())->flags &=
                                       ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
                                   return v;
                               })
        .def_property_readonly("features",
                               [](PP& s) {
                                   py::array_t<double> f({py::ssize_t(s.p->n_ridges()), py::ssize_t(4)});
                                   Claim claim(s.owner);
                                   s.p->last_features(f.mutable_data());
                                   return f;
                               })
        .def_property_readonly("last_accepted", [](const PP& s) { return s.last_ok.load(); })
        .def_property_readonly("status", [](const PP& s) { return status_dict(s.p->published_status()); })
        .def_property_readonly("controller_state",
                               [](PP& s) {
                                   Claim claim(s.owner);
                                   const auto& c = s.p->controller();
                                   py::dict d;
                                   d["position"] = c.position();
                                   d["command"] = c.command();
                                   d["velocity"] = c.velocity();
                                   d["asymmetry"] = c.asymmetry();
                                   d["direction"] = c.direction();
                                   return d;
                               })
        .def(
            "reset",
            [](PP& s, double x0) {
                finite_position(x0, "x0");
                Claim claim(s.owner);
                s.p->reset(x0);
                s.last_ok = true;
            },
            py::arg("x0") = 0.0)
        .def(
            "set_position",
            [](PP& s, double x) {
                finite_position(x, "x");
                Claim claim(s.owner);
                s.p->set_position(x);
            },
            py::arg("x"))
        .def(
            "time_step_ns",
            [](PP& s, long n_iter, int repeats) {
                if (n_iter < 1) throw py::value_error("n_iter must be >= 1");
                if (repeats < 1) throw py::value_error("repeats must be >= 1");
                Claim claim(s.owner);
                py::gil_scoped_release release;
                return s.p->time_step_ns(n_iter, repeats);
            },
            py::arg("n_iter") = 200000, py::arg("repeats") = 5,
            "Mean ns of one tick measured inside C++ over n_iter ticks (best of repeats); state restored.");
}

}  // namespace

void tm_bind_pipeline(py::module_& m) {
    m.def(
        "controller_fields",
        []() {
            py::list out;
            std::size_t nf = 0;
            const tactile::ControllerField* fields = tactile::controller_fields(&nf);
            for (std::size_t i = 0; i < nf; ++i) {
                py::list laws;
                if (fields[i].laws & 1) laws.append("paper");
                if (fields[i].laws & 2) laws.append("velocity");
                out.append(py::make_tuple(fields[i].name, py::tuple(laws), fields[i].doc));
            }
            return out;
        },
        "The controller parameters, in order: (name, laws that read it, meaning). The one definition "
        "(pipeline.hpp) that the C ABI, the pipeline and the Python dataclasses share.");
    m.def(
        "controller_defaults",
        [](const std::string& kind) { return controller_dict(tactile::default_controller(kind_from(kind))); },
        py::arg("kind"), "Default parameters of a law ('none', 'paper' or 'velocity'), as a dict.");
    m.def(
        "pipeline_defaults",
        []() {
            const PipelineConfig c;
            py::dict d;
            d["v_limit"] = c.v_limit;
            d["u_limit"] = c.u_limit;
            d["slip_threshold"] = c.slip_threshold;
            d["max_hold_ticks"] = c.max_hold_ticks;
            d["force_limit"] = c.force_limit;
            return d;
        },
        "Defaults of the pipeline configuration shared with the C ABI (v_limit, u_limit: the front end's "
        "output swing, V; force_limit: a load cell's range, N).");
    bind_one<double, double>(m, "_MirrorPipelineF64");
    bind_one<float, float>(m, "_MirrorPipelineF32");
    bind_one<double, float>(m, "_MirrorPipelineF64F32");
}
