// The checks of tests/cpp/test_jordan.cpp for float (jordan_checks.hpp), compiled on
// their own and linked with test_jordan.cpp.
#include "jordan_checks.hpp"

namespace jordan_test {
TM_JORDAN_CHECKS(, float)
}  // namespace jordan_test
