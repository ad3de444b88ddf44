"""Build the C ABI library and the C test program with AddressSanitizer and
UndefinedBehaviorSanitizer, and run the program.

    python tests/run_sanitizers.py [--build-dir DIR] [--keep]

Configures CMake with ``-DTM_C_ONLY=ON -DTM_SANITIZE=ON -DTM_BUILD_C_TESTS=ON``
(no Python module: only ``src/cpp`` and ``tests/c/example.c``), builds in Debug
and runs ``tm_c_example`` with ``detect_leaks=1`` and ``halt_on_error=1``. The
program exercises the whole C++ pipeline (filters, detector, controllers) and
every error path of the C ABI. Exit status 0 when the build and the run are
clean. Takes about a minute on two cores.
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build-dir", type=Path, default=None)
    ap.add_argument("--keep", action="store_true", help="keep the temporary build directory")
    args = ap.parse_args(argv)
    return run(args.build_dir, args.keep)


if __name__ == "__main__":
    sys.exit(main())
