// The compiled core of tactile_mirror. Each data-flow stage binds itself in its
// own translation unit (bind_*.cpp); this file only assembles the module.
#include <pybind11/pybind11.h>

namespace py = pybind11;

void tm_bind_sos(py::module_& m);
void tm_bind_detector(py::module_& m);
void tm_bind_pipeline(py::module_& m);
void tm_bind_contact(py::module_& m);

PYBIND11_MODULE(_core, m) {
    m.doc() = "tactile_mirror C++ core: SOS filters, slip-detector kernel, real-time pipeline";
    tm_bind_sos(m);
    tm_bind_detector(m);
    tm_bind_pipeline(m);
    tm_bind_contact(m);
}
