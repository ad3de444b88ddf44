// The compiled core of tactile_mirror. Each data-flow stage binds itself in its
// own translation unit (bind_*.cpp); this file assembles the module and binds the
// process-wide baseline switch of the SIMD layer (simd.hpp).
#include <pybind11/pybind11.h>

#include <cstdlib>
#include <cstring>
#include <string>

#include "simd.hpp"

namespace py = pybind11;

void tm_bind_sos(py::module_& m);
void tm_bind_detector(py::module_& m);
void tm_bind_pipeline(py::module_& m);
void tm_bind_contact(py::module_& m);

PYBIND11_MODULE(_core, m) {
    m.doc() = "tactile_mirror C++ core: SOS filters, slip-detector kernel, real-time pipeline";
    // TM_SIMD is read once, here at import: "baseline" starts the process on the baseline kernels.
    const char* simd_env = std::getenv("TM_SIMD");
    if (simd_env != nullptr && *simd_env != '\0' && std::strcmp(simd_env, "auto") != 0 &&
        std::strcmp(simd_env, "baseline") != 0)
        throw py::import_error("the environment variable TM_SIMD must be 'baseline' or 'auto' (or unset), got '" +
                               std::string(simd_env) + "'");
    (void)tactile::simd::baseline_forced();
    tm_bind_sos(m);
    tm_bind_detector(m);
    tm_bind_pipeline(m);
    tm_bind_contact(m);
    m.def("_set_baseline", [](bool on) { tactile::simd::set_baseline(on); }, py::arg("on"),
          "Hold every kernel of this process to the baseline variant (on=True; objects built from now on, and "
          "every contact solve), or return to the CPU's best variant (on=False). Process-wide.");
    m.def("_baseline_forced", []() { return tactile::simd::baseline_forced(); },
          "Whether the kernels are held to the baseline variant now (_set_baseline, TM_SIMD=baseline).");
}
