// pybind11 bindings of the SOS engine (sos.hpp). Validation that needs Python
// knowledge (argument names in messages, scipy's dtype rules) lives in
// tactile_mirror/filters.py; these bindings check what the kernel relies on.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <chrono>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "owner.hpp"
#include "sos.hpp"

namespace py = pybind11;

namespace {

template <typename T>
struct PyCascade {
    tactile::SosCascade<T> k;
    tactile::OwnerFlag owner;  // one call at a time: block calls run without the GIL
    // step(): samples whose update would have made the state non-finite (rejected
    // here, on top of the kernel's count of non-finite samples), the state before
    // a step (its undo) and the last accepted output (held on a rejection).
    std::uint64_t overflow = 0;
    std::vector<T> undo, held;
    bool hold_override = false;  // since the last overflow the kernel's held output is not the last accepted
    PyCascade(const double* sos, std::size_t ns, std::size_t ch, const tactile::SectionForm* f)
        : k(sos, ns, ch, f), undo(k.raw_state_size()), held(ch, T(0)) {}
};

template <typename T>
class BusyLock {
public:
    explicit BusyLock(PyCascade<T>& c) : claim_(c.owner) {
        if (!claim_.owns()) throw std::runtime_error("this filter is being used by another thread");
    }

private:
    tactile::OwnerClaim claim_;
};

template <typename T>
bool all_finite(const T* a, std::size_t n) {
    bool ok = true;
    for (std::size_t i = 0; i < n; ++i) ok &= std::fabs(a[i]) <= std::numeric_limits<T>::max();
    return ok;
}

std::string shape_str(const py::array& a) {
    std::string s = "(";
    for (py::ssize_t i = 0; i < a.ndim(); ++i) {
        s += std::to_string(a.shape(i));
        if (a.ndim() == 1) s += ",";
        else if (i + 1 < a.ndim()) s += ", ";
    }
    return s + ")";
}

// A 1-D sample of `n` values of type T: the given array itself when it already is
// one, else a converted copy. Non-real dtypes are a TypeError.
template <typename T>
py::array_t<T, py::array::c_style | py::array::forcecast> as_sample(py::handle obj, std::size_t n, const char* name) {
    py::array a = py::array::ensure(obj);
    if (!a) throw py::type_error(std::string(name) + " must be an array of real numbers");
    char kind = a.dtype().kind();
    if (kind != 'f' && kind != 'i' && kind != 'u')
        throw py::type_error(std::string(name) + " must hold real numbers, got dtype " +
                             std::string(py::str(a.dtype())));
    if (a.ndim() != 1 || static_cast<std::size_t>(a.shape(0)) != n)
        throw py::value_error(std::string(name) + " must have shape (" + std::to_string(n) + ",), got " +
                              shape_str(a));
    // Any real dtype is converted (float64 -> float32 included): the filter's
    // dtype is the caller's choice of precision.
    auto out = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(a);
    if (!out) throw py::error_already_set();
    return out;
}

template <typename T>
void bind_cascade(py::module_& m, const char* name) {
    using C = PyCascade<T>;
    py::class_<C>(m, name,
                  "Multi-channel SOS cascade (see sos.hpp). Use tactile_mirror.SosFilter instead.")
        .def(py::init([](py::array_t<double, py::array::c_style | py::array::forcecast> sos,
                         std::size_t channels, py::array_t<std::uint8_t, py::array::c_style> forms) {
                 if (sos.ndim() != 2 || sos.shape(1) != 6)
                     throw py::value_error("sos must have shape (n_sections, 6)");
                 std::size_t ns = static_cast<std::size_t>(sos.shape(0));
                 if (forms.ndim() != 1 || static_cast<std::size_t>(forms.shape(0)) != ns)
                     throw py::value_error("forms must have one entry per section");
                 for (std::size_t i = 0; i < ns; ++i)
                     if (forms.data()[i] > 1) throw py::value_error("forms entries must be 0 (tdf2) or 1 (delta)");
                 return new C(sos.data(), ns, channels,
                              reinterpret_cast<const tactile::SectionForm*>(forms.data()));
             }),
             py::arg("sos"), py::arg("channels"), py::arg("forms"))
        .def_property_readonly("channels", [](C& c) { return c.k.channels(); })
        .def_property_readonly("sections", [](C& c) { return c.k.sections(); })
        .def_property_readonly("isa", [](C& c) { return std::string(tactile::simd::isa_name(c.k.isa())); })
        .def(
            "use_baseline_isa",
            [](C& c) {
                BusyLock<T> lock(c);
                c.k.set_isa(tactile::simd::Isa::baseline);
            },
            "Run the portable baseline kernels (testing aid).")
        .def_property_readonly("rejected", [](C& c) { return c.k.rejected() + c.overflow; },
                               "number of step() samples rejected: non-finite, or overflowing the state")
        .def(
            "process",
            [](C& c, py::array_t<T, 0> x, bool guard_state) -> py::tuple {
                // x: (channels, n), any strides. Returns (y, bad_t, bad_c) with
                // bad_t = -1 on success; the state is unchanged when bad_t >= 0.
                // guard_state: a block whose outputs or final state are not finite
                // (finite samples that overflow) raises ValueError, state unchanged.
                if (x.ndim() != 2 || static_cast<std::size_t>(x.shape(0)) != c.k.channels())
                    throw py::value_error("x must have shape (" + std::to_string(c.k.channels()) +
                                          ", n), got " + shape_str(x));
                if (x.strides(0) % py::ssize_t(sizeof(T)) || x.strides(1) % py::ssize_t(sizeof(T))) {
                    auto contiguous = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(x);
                    if (!contiguous) throw py::error_already_set();
                    x = contiguous;
                }
                const std::size_t n = static_cast<std::size_t>(x.shape(1));
                py::array_t<T> y({static_cast<py::ssize_t>(c.k.channels()), static_cast<py::ssize_t>(n)});
                std::size_t bt = 0, bc = 0;
                bool ok;
                std::ptrdiff_t over_t = -1, over_c = -1;
                {
                    BusyLock<T> lock(c);
                    const T* xp = x.data();
                    T* yp = y.mutable_data();
                    const std::ptrdiff_t xsc = x.strides(0) / py::ssize_t(sizeof(T));
                    const std::ptrdiff_t xst = x.strides(1) / py::ssize_t(sizeof(T));
                    const std::size_t ns = c.k.raw_state_size(), ch = c.k.channels();
                    // The held output is part of what a refused block leaves as it was: step()
                    // returns it on a rejected sample.
                    std::vector<T> held_before(c.k.held_output(), c.k.held_output() + ch);
                    py::gil_scoped_release nogil;
                    if (guard_state) std::copy(c.k.raw_state(), c.k.raw_state() + ns, c.undo.data());
                    ok = c.k.process(xp, xsc, xst, yp, static_cast<std::ptrdiff_t>(n), 1, n, &bt, &bc);
                    if (ok && guard_state &&
                        !(all_finite(yp, ch * n) && all_finite(c.k.raw_state(), ns))) {
                        c.k.load_raw_state(c.undo.data());
                        c.k.load_held_output(held_before.data());
                        over_t = std::ptrdiff_t(n) - 1;
                        over_c = 0;
                        for (std::size_t t = 0; t < n && over_t == std::ptrdiff_t(n) - 1; ++t)
                            for (std::size_t ci = 0; ci < ch; ++ci)
                                if (!tactile::is_finite(yp[ci * n + t])) {
                                    over_t = std::ptrdiff_t(t);
                                    over_c = std::ptrdiff_t(ci);
                                    break;
                                }
                    } else if (ok && n > 0) {
                        // accepted: its last outputs are the held ones, also for step()'s
                        // wrapper, whose own held copy dates from before the block
                        for (std::size_t ci = 0; ci < ch; ++ci) c.held[ci] = yp[ci * n + n - 1];
                        c.hold_override = false;
                    }
                }
                if (over_t >= 0)
                    throw py::value_error(
                        "block overflows the filter (a non-finite output or state from finite samples) at channel " +
                        std::to_string(over_c) + ", sample " + std::to_string(over_t) +
                        "; the filter state is unchanged");
                if (ok) return py::make_tuple(y, py::ssize_t(-1), py::ssize_t(-1));
                return py::make_tuple(py::none(), static_cast<py::ssize_t>(bt), static_cast<py::ssize_t>(bc));
            },
            py::arg("x"), py::arg("guard_state") = false)
        .def(
            "_snapshot",
            [](C& c) {
                py::array_t<T> s(static_cast<py::ssize_t>(c.k.raw_state_size()));
                py::array_t<T> h(static_cast<py::ssize_t>(c.k.channels()));
                BusyLock<T> lock(c);
                std::copy(c.k.raw_state(), c.k.raw_state() + c.k.raw_state_size(), s.mutable_data());
                std::copy(c.k.held_output(), c.k.held_output() + c.k.channels(), h.mutable_data());
                return py::make_tuple(s, h);
            },
            "The raw state and the held output, bit for bit (internal layout): what process() changes, "
            "for a caller that undoes a process() call with _restore().")
        .def(
            "_restore",
            [](C& c, py::array_t<T, py::array::c_style | py::array::forcecast> s,
               py::array_t<T, py::array::c_style | py::array::forcecast> h) {
                if (s.ndim() != 1 || static_cast<std::size_t>(s.shape(0)) != c.k.raw_state_size() || h.ndim() != 1 ||
                    static_cast<std::size_t>(h.shape(0)) != c.k.channels())
                    throw py::value_error("not a snapshot of this filter");
                BusyLock<T> lock(c);
                c.k.load_raw_state(s.data());
                c.k.load_held_output(h.data());
            },
            py::arg("state"), py::arg("held"), "Load what _snapshot() returned.")
        .def(
            "step",
            [](C& c, py::handle sample) {
                auto x = as_sample<T>(sample, c.k.channels(), "sample");
                const std::size_t ch = c.k.channels(), ns = c.k.raw_state_size();
                py::array_t<T> y(static_cast<py::ssize_t>(ch));
                T* yp = y.mutable_data();
                BusyLock<T> lock(c);
                std::copy(c.k.raw_state(), c.k.raw_state() + ns, c.undo.data());
                if (c.k.step(x.data(), yp)) {
                    if (all_finite(yp, ch) && all_finite(c.k.raw_state(), ns)) {
                        std::copy(yp, yp + ch, c.held.data());
                        c.hold_override = false;
                        return y;
                    }
                    c.k.load_raw_state(c.undo.data());  // overflow: as a rejected sample
                    ++c.overflow;
                    c.hold_override = true;
                }
                // Rejected: the kernel returned its held output, unless an overflow
                // (whose output it took as its last) came after the last accepted sample.
                if (c.hold_override) std::copy(c.held.begin(), c.held.end(), yp);
                return y;
            },
            py::arg("sample"),
            "Filter one sample per channel. A sample with a NaN/Inf value, or one whose update would make an "
            "output or the state non-finite, is rejected: the state is kept, the rejection counted "
            "(``rejected``), and the previous output returned.")
        .def("get_state",
             [](C& c) {
                 py::array_t<T> zi({static_cast<py::ssize_t>(c.k.sections()),
                                    static_cast<py::ssize_t>(c.k.channels()), py::ssize_t(2)});
                 BusyLock<T> lock(c);  // a block call on another thread would tear it
                 c.k.get_state(zi.mutable_data());
                 return zi;
             })
        .def(
            "set_state",
            [](C& c, py::array_t<T, py::array::c_style | py::array::forcecast> zi) {
                if (zi.ndim() != 3 || static_cast<std::size_t>(zi.shape(0)) != c.k.sections() ||
                    static_cast<std::size_t>(zi.shape(1)) != c.k.channels() || zi.shape(2) != 2)
                    throw py::value_error("zi must have shape (" + std::to_string(c.k.sections()) + ", " +
                                          std::to_string(c.k.channels()) + ", 2), got " + shape_str(zi));
                const T* p = zi.data();
                for (py::ssize_t i = 0; i < zi.size(); ++i)
                    if (!tactile::is_finite(p[i])) throw py::value_error("zi must be finite");
                BusyLock<T> lock(c);
                c.k.set_state(p);
                c.hold_override = false;
            },
            py::arg("zi"))
        .def("reset",
             [](C& c) {
                 BusyLock<T> lock(c);
                 c.k.reset();
                 c.overflow = 0;
                 c.hold_override = false;
             })
        .def(
            "time_step",
            [](C& c, std::size_t n_steps, bool thread_ftz) {
                // Benchmark: ns per step() timed inside C++ over a cycled input of
                // 1024 pseudo-random samples (state is reset afterwards). With
                // thread_ftz the loop runs under one DenormalGuard, as a real-time
                // thread that enables flush-to-zero once would; otherwise every
                // step() sets and restores MXCSR itself.
                const std::size_t ch = c.k.channels();
                std::vector<T> xs(1024 * ch), y(ch);
                std::uint64_t r = 88172645463325252ull;
                for (auto& v : xs) {
                    r ^= r << 13; r ^= r >> 7; r ^= r << 17;
                    v = static_cast<T>(double(r >> 11) * (1.0 / 9007199254740992.0) - 0.5);
                }
                BusyLock<T> lock(c);
                py::gil_scoped_release nogil;
                std::chrono::steady_clock::time_point t0, t1;
                if (thread_ftz) {
                    tactile::DenormalGuard ftz;
                    t0 = std::chrono::steady_clock::now();
                    for (std::size_t i = 0; i < n_steps; ++i) c.k.step(xs.data() + (i & 1023) * ch, y.data());
                    t1 = std::chrono::steady_clock::now();
                } else {
                    t0 = std::chrono::steady_clock::now();
                    for (std::size_t i = 0; i < n_steps; ++i) c.k.step(xs.data() + (i & 1023) * ch, y.data());
                    t1 = std::chrono::steady_clock::now();
                }
                c.k.reset();
                return std::chrono::duration<double, std::nano>(t1 - t0).count() / double(n_steps);
            },
            py::arg("n_steps"), py::arg("thread_ftz") = false);
}

}  // namespace

void tm_bind_sos(py::module_& m) {
    bind_cascade<double>(m, "_SosCascade64");
    bind_cascade<float>(m, "_SosCascade32");
    m.def("simd_path", []() { return std::string(tactile::simd::isa_name(tactile::simd::detect_isa())); },
          "The code variant of the SIMD layer (simd.hpp) that every C++ kernel built now runs: "
          "'avx2+fma', 'sse2' (x86-64 baseline, also while the baseline switch is on), 'native' "
          "(-DTM_NATIVE=ON build) or 'generic' (other CPUs).");
}
