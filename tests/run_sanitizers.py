"""Build the C ABI library and the C test program with AddressSanitizer and
UndefinedBehaviorSanitizer, and run the program.

    python tests/run_sanitizers.py [--build-dir DIR | --fresh [--keep]]
    python tests/run_sanitizers.py --thread [--build-dir DIR | --fresh [--keep]]

Configures CMake with ``-DTM_C_ONLY=ON -DTM_SANITIZE=ON -DTM_BUILD_C_TESTS=ON``
(no Python module: only ``src/cpp`` and ``tests/c/example.c``), builds in Debug
and runs ``tm_c_example`` with ``detect_leaks=1`` and ``halt_on_error=1``. The
program exercises the whole C++ pipeline (filters, detector, controllers) and
every error path of the C ABI. Exit status 0 when the build and the run are
clean. The build takes about two minutes of one core.

``--thread`` builds the library and ``tests/c/close_while_stepping.c`` with
ThreadSanitizer (the compiler directly, ``-O0 -g``) and runs it with
``halt_on_error=1``: threads stepping, reading and destroying one handle at once.
Exit status 77 (skipped) when the compiler or the system cannot run
ThreadSanitizer programs. The build takes about three minutes of one core.

The builds are made by ``tests/_native_build.py``: by default in the shared cache
under ``build/native-tests/``, where a build is reused as long as its sources,
headers, flags and compilers are unchanged (the tests build there too, and wait
for each other instead of building the same thing twice); ``--build-dir DIR``
builds in DIR instead (reused there on the same terms), ``--fresh`` in a new
temporary directory, removed afterwards unless ``--keep``.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _native_build as nb

SKIP = 77


def _build(spec: nb.Spec, build_dir: Path | None) -> Path | None:
    """The spec's artefact, built in ``build_dir`` or the shared cache; None (and the
    compiler's message on stderr) if the build failed."""
    try:
        return spec.build(where=build_dir)
    except nb.BuildError as e:
        sys.stdout.write(e.stdout or "")
        sys.stderr.write(f"{' '.join(map(str, e.cmd))}: exit status {e.returncode}\n{e.stderr or ''}")
        return None


def _build_dir(build_dir: Path | None, fresh: bool, prefix: str) -> tuple[Path | None, str | None]:
    if fresh and build_dir is None:
        tmp = tempfile.mkdtemp(prefix=prefix)
        return Path(tmp), tmp
    return build_dir, None


def run(build_dir: Path | None = None, keep: bool = False, fresh: bool = False) -> int:
    build_dir, tmp = _build_dir(build_dir, fresh, "tm-sanitize-")
    try:
        if shutil.which("cmake") is None:
            print("cmake not found", file=sys.stderr)
            return 2
        exe = _build(nb.capi_asan(), build_dir)
        if exe is None:
            return 1
        env = dict(os.environ)
        env["ASAN_OPTIONS"] = "detect_leaks=1:halt_on_error=1:abort_on_error=0"
        env["UBSAN_OPTIONS"] = "print_stacktrace=1:halt_on_error=1"
        r = subprocess.run([str(exe)], check=False, env=env, capture_output=True, text=True)
        sys.stdout.write(r.stdout)
        sys.stderr.write(r.stderr)
        if r.returncode != 0 or "runtime error" in r.stderr or "ERROR: AddressSanitizer" in r.stderr:
            return 1
        return 0
    finally:
        if tmp is not None and not keep:
            shutil.rmtree(tmp, ignore_errors=True)


def run_thread(build_dir: Path | None = None, keep: bool = False, fresh: bool = False) -> int:
    build_dir, tmp = _build_dir(build_dir, fresh, "tm-tsan-")
    try:
        cc, cxx = nb.cc_cxx()
        if cxx is None or cc is None:
            print("no C/C++ compiler", file=sys.stderr)
            return SKIP
        if not nb.thread_sanitizer_runs(cc, ".c"):
            print("the compiler cannot build or run ThreadSanitizer programs here", file=sys.stderr)
            return SKIP
        exe = _build(nb.capi_tsan(), build_dir)
        if exe is None:
            return 1
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
    ap.add_argument("--build-dir", type=Path, default=None,
                    help="build here (default: the shared cache under build/native-tests/)")
    ap.add_argument("--fresh", action="store_true", help="build in a new temporary directory")
    ap.add_argument("--keep", action="store_true", help="with --fresh: keep the temporary build directory")
    ap.add_argument("--thread", action="store_true",
                    help="ThreadSanitizer on tests/c/close_while_stepping.c instead of ASan/UBSan on example.c")
    args = ap.parse_args(argv)
    if args.thread:
        return run_thread(args.build_dir, args.keep, args.fresh)
    return run(args.build_dir, args.keep, args.fresh)


if __name__ == "__main__":
    sys.exit(main())
