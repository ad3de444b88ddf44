"""Build the C ABI library and the C test program with AddressSanitizer and
UndefinedBehaviorSanitizer, and run the program.

    python tests/run_sanitizers.py [--build-dir DIR] [--keep]
    python tests/run_sanitizers.py --thread [--build-dir DIR] [--keep]

Configures CMake with ``-DTM_C_ONLY=ON -DTM_SANITIZE=ON -DTM_BUILD_C_TESTS=ON``
(no Python module: only ``src/cpp`` and ``tests/c/example.c``), builds in Debug
and runs ``tm_c_example`` with ``detect_leaks=1`` and ``halt_on_error=1``. The
program exercises the whole C++ pipeline (filters, detector, controllers) and
every error path of the C ABI. Exit status 0 when the build and the run are
clean. Takes about a minute on two cores.

``--thread`` builds the library and ``tests/c/close_while_stepping.c`` with
ThreadSanitizer (the compiler directly, ``-O1 -g``) and runs it with
``halt_on_error=1``: threads stepping, reading and destroying one handle at once.
Exit status 77 (skipped) when the compiler or the system cannot run
ThreadSanitizer programs. Takes one to three minutes on two cores.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(build_dir: Path | None = None, keep: bool = False, jobs: int = 2) -> int:
    tmp = None
    if build_dir is None:
        tmp = tempfile.mkdtemp(prefix="tm-sanitize-")
        build_dir = Path(tmp)
    try:
        cmake = shutil.which("cmake")
        if cmake is None:
            print("cmake not found", file=sys.stderr)
            return 2
        cfg = [cmake, "-S", str(ROOT), "-B", str(build_dir), "-DTM_C_ONLY=ON", "-DTM_SANITIZE=ON",
               "-DTM_BUILD_C_TESTS=ON", "-DCMAKE_BUILD_TYPE=Debug"]
        subprocess.run(cfg, check=True, stdout=subprocess.DEVNULL)
        subprocess.run([cmake, "--build", str(build_dir), "-j", str(jobs), "--target", "tm_c_example"], check=True,
                       stdout=subprocess.DEVNULL)
        env = dict(os.environ)
        env["ASAN_OPTIONS"] = "detect_leaks=1:halt_on_error=1:abort_on_error=0"
        env["UBSAN_OPTIONS"] = "print_stacktrace=1:halt_on_error=1"
        exe = build_dir / "tm_c_example"
        r = subprocess.run([str(exe)], check=False, env=env, capture_output=True, text=True)
        sys.stdout.write(r.stdout)
        sys.stderr.write(r.stderr)
        if r.returncode != 0 or "runtime error" in r.stderr or "ERROR: AddressSanitizer" in r.stderr:
            return 1
        return 0
    finally:
        if tmp is not None and not keep:
            shutil.rmtree(tmp, ignore_errors=True)


SKIP = 77


def run_thread(build_dir: Path | None = None, keep: bool = False) -> int:
    tmp = None
    if build_dir is None:
        tmp = tempfile.mkdtemp(prefix="tm-tsan-")
        build_dir = Path(tmp)
    build_dir.mkdir(parents=True, exist_ok=True)
    try:
        cxx = shutil.which(os.environ.get("CXX", "c++")) or shutil.which("g++") or shutil.which("clang++")
        cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc") or shutil.which("clang")
        if cxx is None or cc is None:
            print("no C/C++ compiler", file=sys.stderr)
            return SKIP
        probe = build_dir / "probe.c"
        probe.write_text("int main(void) { return 0; }\n")
        p = subprocess.run([cc, "-fsanitize=thread", str(probe), "-o", str(build_dir / "probe")],
                           check=False, capture_output=True, text=True)
        runs = p.returncode == 0 and subprocess.run([str(build_dir / "probe")], check=False,
                                                    capture_output=True).returncode == 0
        if not runs:
            print("the compiler cannot build or run ThreadSanitizer programs here", file=sys.stderr)
            return SKIP
        src = ROOT / "src" / "cpp"
        lib = build_dir / "libtactile_mirror_c_tsan.so"
        flags = ["-O1", "-g", "-fsanitize=thread", "-fno-omit-frame-pointer", "-DTM_LEAN_UNROLL"]
        subprocess.run([cxx, "-std=c++17", *flags, "-fPIC", "-shared", "-Wno-psabi", "-I", str(src),
                        str(src / "tm_capi.cpp"), "-o", str(lib), "-lpthread"], check=True)
        exe = build_dir / "close_while_stepping"
        subprocess.run([cc, "-std=c11", *flags, "-I", str(src), str(ROOT / "tests" / "c" / "close_while_stepping.c"),
                        str(lib), "-Wl,-rpath," + str(build_dir), "-lm", "-lpthread", "-o", str(exe)], check=True)
        env = dict(os.environ)
        env["TSAN_OPTIONS"] = "halt_on_error=1:second_deadlock_stack=1"
        r = subprocess.run([str(exe)], check=False, env=env, capture_output=True, text=True, timeout=600)
        sys.stdout.write(r.stdout)
        sys.stderr.write(r.stderr)
        if r.returncode != 0 or "ThreadSanitizer" in r.stderr or "ok" not in r.stdout.split():
            return 1
        return 0
    finally:
        if tmp is not None and not keep:
            shutil.rmtree(tmp, ignore_errors=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build-dir", type=Path, default=None)
    ap.add_argument("--keep", action="store_true", help="keep the temporary build directory")
    ap.add_argument("--thread", action="store_true",
                    help="ThreadSanitizer on tests/c/close_while_stepping.c instead of ASan/UBSan on example.c")
    args = ap.parse_args(argv)
    if args.thread:
        return run_thread(args.build_dir, args.keep)
    return run(args.build_dir, args.keep)


if __name__ == "__main__":
    sys.exit(main())
