// The stand-alone kernel tests' check: report a failed condition and count it
// (the program then prints "ok: N failures" and exits non-zero if N > 0). One
// count per program, also when it is built from several translation units.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <vector>

inline int failures = 0;
#define CHECK(cond, ...)                                              \
    do {                                                              \
        if (!(cond)) {                                                \
            std::fprintf(stderr, "FAIL %s:%d: ", __FILE__, __LINE__); \
            std::fprintf(stderr, __VA_ARGS__);                        \
            std::fprintf(stderr, "\n");                               \
            ++failures;                                               \
        }                                                             \
    } while (0)

// n values of type T from a reference file written by the Python side (numpy tofile);
// a short file ends the program with status 2
template <typename T>
static std::vector<T> read(std::FILE* f, std::size_t n) {
    std::vector<T> v(n);
    if (n && std::fread(v.data(), sizeof(T), n, f) != n) {
        std::fprintf(stderr, "short read\n");
        std::exit(2);
    }
    return v;
}
