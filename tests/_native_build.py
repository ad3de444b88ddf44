"""Native builds for the tests (the sanitizer builds above all), each made once and reused.

A build is described by a ``Spec``: its name, the compiler commands that make it and
its inputs. It is made in a directory of its own under ``build/native-tests/`` (git
ignores ``build/``; ``TM_NATIVE_TEST_CACHE`` names another directory) whose name holds
a hash of everything that goes into it: the contents of every header in ``src/cpp``
and ``tests/cpp`` (whatever headers there are), of the build's own sources, of this
file (the recipes), the commands and flags, and the compilers' identity. A changed
input gives a new directory, so a stale build is never reused; the directory it
replaces is removed once no process uses it.

The processes of a test run (the two pytest-xdist workers, ``tests/run_sanitizers.py``
started by a test) share the directories through ``fcntl.flock`` locks: the first
process to need a build makes it holding the directory's ``.build`` lock, any other
waits for that lock and then finds the build done (a stamp file holding its key).
Every process holds a shared lock on the ``.lock`` of each build it uses until it
exits; a directory is removed as stale only by a process that gets that lock
exclusively, so never under a user. At most ``TM_NATIVE_TEST_JOBS`` (default 2)
compilers run at once over all these processes: each compiler holds one of that many
slot locks, taken in turn (those of a build a test is waiting for first). ccache is
used when it is on the PATH (never required).

The compile and link steps are separate commands (ccache caches compiles only), and
a program built from several translation units has them compiled in parallel. The
tests/conftest.py hooks start the builds the selected tests need in a background
thread of each test process (``start_background``), costliest first; every command
is logged with its duration in ``build.log`` of the cache.
"""
from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "cpp"
TESTS = ROOT / "tests"
STAMP = "BUILT"
LOCK = ".lock"
WANTED = ".wanted"


def cache_root() -> Path:
    env = os.environ.get("TM_NATIVE_TEST_CACHE")
    return Path(env).resolve() if env else ROOT / "build" / "native-tests"


def jobs() -> int:
    try:
        return max(1, int(os.environ.get("TM_NATIVE_TEST_JOBS", "2")))
    except ValueError:
        return 2


def launcher() -> list[str]:
    """``ccache`` before every compile command where it is installed."""
    cc = shutil.which("ccache")
    return [cc] if cc else []


class BuildError(subprocess.CalledProcessError):
    """A failed command of a build; its message ends with the command's output."""

    def __str__(self) -> str:
        out = ((self.stdout or "") + (self.stderr or "")).strip()
        return super().__str__() + ("\n" + out[-8000:] if out else "")


# -- the compiler commands ---------------------------------------------------------------

_tls = threading.local()  # .background: a background build; .building: the directory being built
_procs: set[subprocess.Popen] = set()
_procs_lock = threading.Lock()
_cancelled = threading.Event()
_no_more = threading.Event()
_threads: list[threading.Thread] = []


def _slot_dir() -> Path:
    d = cache_root() / "slots"
    d.mkdir(parents=True, exist_ok=True)
    return d


def _take_slot(background: bool, building: Path | None) -> int:
    """Wait for one of the jobs() compiler slots shared by every process using the
    cache, in turn: the waiters queue up (a ticket file each), the commands of builds
    a test is waiting for (``WANTED`` in the build's directory) before those of
    background builds, each kind first come first served. Returns the slot's locked
    descriptor."""
    n, d = jobs(), _slot_dir()
    q = d / "queue"
    q.mkdir(exist_ok=True)

    def rank() -> int:
        return int(background and not (building is not None and (building / WANTED).exists()))

    tail = f"{time.time_ns():020d}-{os.getpid()}-{threading.get_ident()}"
    ticket = f"{rank()}-{tail}"
    (q / ticket).touch()
    try:
        while True:
            if ticket[0] == "1" and rank() == 0:  # a test now waits for this build
                with contextlib.suppress(FileNotFoundError):
                    os.rename(q / ticket, q / f"0-{tail}")
                ticket = f"0-{tail}"
            if not _waiter_ahead(q, ticket):
                for k in range(n):
                    fd = os.open(d / f"{k}.lock", os.O_RDWR | os.O_CREAT, 0o666)
                    if _flock(fd, fcntl.LOCK_EX, wait=False):
                        return fd
                    os.close(fd)
            time.sleep(0.05)
    finally:
        with contextlib.suppress(FileNotFoundError):
            (q / ticket).unlink()


def _waiter_ahead(q: Path, ticket: str) -> bool:
    for t in sorted(os.listdir(q)):
        if t >= ticket:
            return False
        try:
            os.kill(int(t.split("-")[2]), 0)
        except (ValueError, IndexError, ProcessLookupError):  # left by a process that died
            with contextlib.suppress(FileNotFoundError):
                (q / t).unlink()
            continue
        except PermissionError:
            pass
        return True
    return False


@contextlib.contextmanager
def _slot():
    fd = _take_slot(getattr(_tls, "background", False), getattr(_tls, "building", None))
    try:
        yield
    finally:
        os.close(fd)


def _log(line: str) -> None:
    """One line per command in build.log of the cache: when it started, how long it took."""
    log = cache_root() / "build.log"
    with contextlib.suppress(OSError):
        if log.stat().st_size > 1 << 20:
            os.replace(log, log.with_suffix(".log.old"))
    with contextlib.suppress(OSError), open(log, "a") as f:
        f.write(line + "\n")


def run(cmd: Sequence[str], cwd: Path | None = None, env: dict | None = None, slot: bool = True) -> None:
    """Run one build command (in a compiler slot unless ``slot`` is false); BuildError if it fails."""
    with _slot() if slot else contextlib.nullcontext():
        if _cancelled.is_set():
            raise BuildError(-1, list(cmd), "", "cancelled")
        t0 = time.time()
        p = subprocess.Popen(list(cmd), cwd=cwd or ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
        with _procs_lock:
            _procs.add(p)
        try:
            out, err = p.communicate()
        finally:
            with _procs_lock:
                _procs.discard(p)
            _log(f"{time.strftime('%H:%M:%S', time.localtime(t0))} {time.time() - t0:6.1f} s pid {os.getpid()} "
                 f"exit {p.returncode}: {' '.join(map(str, cmd))[-160:]}")
    if p.returncode != 0:
        raise BuildError(p.returncode, list(cmd), out, err)


def run_all(cmds: Sequence[Sequence[str]]) -> None:
    """Run independent commands (compiles), as many at once as there are slots."""
    if len(cmds) <= 1 or jobs() == 1:
        for c in cmds:
            run(c)
        return
    context = (getattr(_tls, "background", False), getattr(_tls, "building", None))

    def one(cmd):
        _tls.background, _tls.building = context
        run(cmd)

    with ThreadPoolExecutor(max_workers=min(jobs(), len(cmds))) as ex:
        for f in [ex.submit(one, c) for c in cmds]:
            f.result()


def finish_background(kill: bool = False) -> None:
    """End the background builds of this process: none is started any more; the one
    under way is finished (another process may be waiting for it), or with ``kill``
    stopped at once (no new command starts, running ones are terminated)."""
    _no_more.set()
    if not kill:
        for t in _threads:
            t.join()
        return
    _cancelled.set()
    with _procs_lock:
        procs = list(_procs)
    for p in procs:
        with contextlib.suppress(OSError):
            p.terminate()


_versions: dict[str, str] = {}


def compiler_id(exe: str | None) -> str:
    """The compiler's path and its ``--version`` text (part of every key)."""
    if exe is None:
        return "none"
    if exe not in _versions:
        r = subprocess.run([exe, "--version"], capture_output=True, text=True, check=False)
        _versions[exe] = os.path.realpath(exe) + "\n" + r.stdout.strip()
    return _versions[exe]


def cxx_compiler() -> str | None:
    return shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")


_tsan: dict[tuple[str, str], bool] = {}


def thread_sanitizer_runs(compiler: str, suffix: str = ".c") -> bool:
    """Whether ``compiler`` builds a ThreadSanitizer program that runs here."""
    if (compiler, suffix) not in _tsan:
        with tempfile.TemporaryDirectory(prefix="tm-tsan-probe-") as d:
            src = Path(d) / ("probe" + suffix)
            src.write_text("int main(void) { return 0; }\n" if suffix == ".c" else "int main() { return 0; }\n")
            p = subprocess.run([compiler, "-fsanitize=thread", str(src), "-o", str(Path(d) / "probe")],
                               check=False, capture_output=True)
            _tsan[(compiler, suffix)] = p.returncode == 0 and subprocess.run(
                [str(Path(d) / "probe")], check=False, capture_output=True).returncode == 0
    return _tsan[(compiler, suffix)]


# -- shared, locked build directories ------------------------------------------------------

def headers() -> list[Path]:
    """Every header the builds may include: the library's and the stand-alone tests'."""
    return sorted([*SRC.glob("*.hpp"), *SRC.glob("*.h"), *(TESTS / "cpp").glob("*.hpp")])


def _digest(parts: Iterable[str], files: Iterable[Path]) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode() + b"\0")
    for f in sorted({Path(f).resolve() for f in files}):
        rel = os.path.relpath(f, ROOT)
        h.update(rel.encode() + b"\0" + hashlib.sha256(f.read_bytes()).digest())
    return h.hexdigest()


class Spec:
    """One build: ``make(dir)`` builds into ``dir``; ``artefact`` names its result there.

    ``parts`` (commands, flags, compilers' identity) and ``inputs`` (files, besides
    ``headers()`` and this module) make the key. ``cost`` (seconds of its longest
    compile, roughly) orders the builds started ahead of the tests; ``needs_tsan`` names the compiler (and source
    suffix) that must run ThreadSanitizer programs for the build to be worth starting."""

    def __init__(self, name: str, make: Callable[[Path], None], artefact: str, parts: Callable[[], list[str]],
                 inputs: Sequence[Path], cost: float = 1.0, needs_tsan: tuple[str, str] | None = None):
        self.name, self.make, self.artefact, self.cost, self.needs_tsan = name, make, artefact, cost, needs_tsan
        self._parts, self._inputs, self._key = parts, list(inputs), None

    @property
    def key(self) -> str:
        if self._key is None:
            self._key = _digest([self.name, *self._parts()], [*headers(), *self._inputs, Path(__file__)])
        return self._key

    def directory(self) -> Path:
        return cache_root() / f"{self.name}-{self.key[:16]}"

    def build(self, where: Path | None = None, wait: bool = True) -> Path | None:
        """The artefact's path, built unless done (in ``where`` or the shared cache).

        With ``wait=False`` returns None at once instead of waiting for another thread
        or process building it."""
        d = self.directory() if where is None else Path(where).resolve()
        ok = _ensure(d, self.key, self.make, wait, prune=self.name if where is None else None)
        return d / self.artefact if ok else None


_thread_locks: dict[Path, threading.Lock] = {}
_held: dict[Path, tuple[int, str]] = {}  # builds in use by this process: a shared lock on each, and the key
_table_lock = threading.Lock()


def _flock(fd: int, mode: int, wait: bool) -> bool:
    try:
        fcntl.flock(fd, mode if wait else mode | fcntl.LOCK_NB)
        return True
    except OSError as e:
        if not wait and e.errno in (errno.EAGAIN, errno.EACCES):
            return False
        raise


def _open_locked(path: Path, mode: int, wait: bool) -> int | None:
    """A descriptor of the lock file ``path``, locked; None if not ``wait`` and it is taken."""
    while True:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        if not _flock(fd, mode, wait):
            os.close(fd)
            return None
        try:
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)  # its directory was removed as stale meanwhile: over again


def _stamp(d: Path) -> str | None:
    try:
        return (d / STAMP).read_text().strip()
    except OSError:
        return None


def _ensure(d: Path, key: str, make: Callable[[Path], None], wait: bool, prune: str | None) -> bool:
    """Make sure ``d`` holds the build ``key``: reuse it, wait for the process making
    it, or make it. Two lock files: ``.lock``, held shared by every process using the
    directory (until it exits) and taken exclusively only to remove the directory;
    ``.build``, held exclusively while the build is made."""
    with _table_lock:
        tl = _thread_locks.setdefault(d, threading.Lock())
    if not tl.acquire(blocking=False):
        if not wait:
            return False
        _want(d)  # this process's background thread is making it
        tl.acquire()
    try:
        held = _held.get(d)
        if held is not None and held[1] == key:
            return True
        if held is not None:  # the same directory for other inputs (an explicit one): let it go
            os.close(_held.pop(d)[0])
        use = _open_locked(d / LOCK, fcntl.LOCK_SH, wait)
        if use is None:
            return False
        try:
            if _stamp(d) != key:
                b = _open_locked(d / ".build", fcntl.LOCK_EX, wait=False)
                if b is None:  # another process is making it
                    if not wait:
                        os.close(use)
                        return False
                    _want(d)
                    b = _open_locked(d / ".build", fcntl.LOCK_EX, wait=True)
                try:
                    if _stamp(d) != key:
                        with contextlib.suppress(FileNotFoundError):
                            (d / STAMP).unlink()
                        _tls.building = d
                        try:
                            make(d)
                        finally:
                            _tls.building = None
                        tmp = d / (STAMP + ".tmp")
                        tmp.write_text(key + "\n")
                        os.replace(tmp, d / STAMP)
                    with contextlib.suppress(FileNotFoundError):
                        (d / WANTED).unlink()
                finally:
                    os.close(b)
        except BaseException:
            os.close(use)
            raise
        _held[d] = (use, key)
    finally:
        tl.release()
    if prune:
        _prune(prune, d)
    return True


def _want(d: Path) -> None:
    """Mark ``d`` as waited for by a test: its commands go first for the compiler slots."""
    with contextlib.suppress(OSError):
        d.mkdir(parents=True, exist_ok=True)
        (d / WANTED).touch()


def _prune(name: str, keep: Path) -> None:
    """Remove the other builds of ``name`` (older inputs) that no process is using."""
    for other in cache_root().glob(name + "-*"):
        tail = other.name[len(name) + 1:]
        if other == keep or len(tail) != 16 or not all(c in "0123456789abcdef" for c in tail):
            continue
        try:
            fd = _open_locked(other / LOCK, fcntl.LOCK_EX, wait=False)
        except OSError:
            continue
        if fd is None:
            continue
        try:
            shutil.rmtree(other, ignore_errors=True)
        finally:
            os.close(fd)


# -- ahead of the tests ----------------------------------------------------------------------

def start_background(specs: Iterable[Spec]) -> threading.Thread | None:
    """Start building ``specs`` (costliest first) in a thread while the tests run.

    A build another process has started is left to it; a failure is left for the test
    that needs the build to report (it builds again and fails with the compiler's
    message)."""
    todo = sorted({id(s): s for s in specs}.values(), key=lambda s: -s.cost)
    if not todo:
        return None

    def work():
        _tls.background = True
        for s in todo:
            if _no_more.is_set():
                return
            with contextlib.suppress(Exception):  # reported by the test that needs the build
                if not s.needs_tsan or thread_sanitizer_runs(*s.needs_tsan):
                    s.build(wait=False)

    t = threading.Thread(target=work, name="native-test-builds", daemon=True)
    t.start()
    _threads.append(t)
    return t


# -- the builds -------------------------------------------------------------------------------

def kernel_program(sources: str | Sequence[str], *, sanitize: bool = True, opt: str = "-O1",
                   sanitizers: str = "address,undefined", debug: bool = True, cost: float = 5.0) -> Spec:
    """A stand-alone kernel test, ``tests/cpp/<sources>`` (the first holds main()), with sanitizers."""
    sources = [sources] if isinstance(sources, str) else list(sources)
    cxx = cxx_compiler()
    flags = ["-std=c++17", opt, *(["-g"] if debug else []), "-Wall", "-Wextra", "-Wno-psabi", "-ffp-contract=fast",
             "-pthread"]
    if sanitize:
        flags += [f"-fsanitize={sanitizers}", "-fno-omit-frame-pointer", "-DTM_LEAN_UNROLL"]
        if "undefined" in sanitizers:
            flags += ["-fno-sanitize-recover=undefined"]
    stem = Path(sources[0]).stem
    paths = [TESTS / "cpp" / s for s in sources]

    def make(d: Path) -> None:
        objs = [d / (p.stem + ".o") for p in paths]
        run_all([[*launcher(), cxx, *flags, f"-I{SRC}", "-c", str(p), "-o", str(o)] for p, o in zip(paths, objs)])
        run([cxx, *flags, *map(str, objs), "-o", str(d / stem)])

    tag = (sanitizers.replace(",", "+") if sanitize else "plain") + opt + ("-g" if debug else "")
    return Spec(f"{stem}-{tag}", make, stem, lambda: [compiler_id(cxx), *flags, *sources], paths, cost=cost,
                needs_tsan=(cxx, ".cpp") if sanitize and "thread" in sanitizers and cxx else None)


def cc_cxx() -> tuple[str | None, str | None]:
    cxx = shutil.which(os.environ.get("CXX", "c++")) or shutil.which("g++") or shutil.which("clang++")
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc") or shutil.which("clang")
    return cc, cxx


def capi_asan() -> Spec:
    """The C ABI library and tests/c/example.c with AddressSanitizer and UBSan: CMake's
    ``TM_C_ONLY``/``TM_SANITIZE``/``TM_BUILD_C_TESTS`` Debug build. Artefact: tm_c_example."""
    cfg = ["-DTM_C_ONLY=ON", "-DTM_SANITIZE=ON", "-DTM_BUILD_C_TESTS=ON", "-DCMAKE_BUILD_TYPE=Debug",
           # UBSan without pointer-overflow: a third of the compile time (130 s of one core
           # against 84 s); ASan still catches the out-of-bounds accesses it would lead to
           "-DTM_SANITIZE_FLAGS=-fsanitize=address,undefined;-fno-sanitize=pointer-overflow"]

    def make(d: Path) -> None:
        cmake = shutil.which("cmake")
        if cmake is None:
            raise BuildError(2, ["cmake"], "", "cmake not found")
        ccache = launcher()
        extra = [f"-DCMAKE_{lang}_COMPILER_LAUNCHER={ccache[0]}" for lang in ("C", "CXX")] if ccache else []
        run([cmake, "-S", str(ROOT), "-B", str(d), *cfg, *extra], slot=False)
        run([cmake, "--build", str(d), "-j", "1", "--target", "tm_c_example"])

    def parts() -> list[str]:
        cmake = shutil.which("cmake")
        v = subprocess.run([cmake, "--version"], capture_output=True, text=True, check=False).stdout if cmake else "none"
        cc, cxx = cc_cxx()
        return [v, compiler_id(cc), compiler_id(cxx), *cfg]

    return Spec("capi-asan", make, "tm_c_example", parts,
                [ROOT / "CMakeLists.txt", SRC / "tm_capi.cpp", TESTS / "c" / "example.c"], cost=85)


# -O0: ThreadSanitizer sees every access at any optimisation level, and the C ABI compiles
# in about a quarter of the -O1 time (31 s of one core against about 110 s).
TSAN_FLAGS = ["-O0", "-g", "-fsanitize=thread", "-fno-omit-frame-pointer", "-DTM_LEAN_UNROLL"]


def capi_tsan() -> Spec:
    """The C ABI library and tests/c/close_while_stepping.c with ThreadSanitizer, by the
    compilers directly (-O0 -g). Artefact: close_while_stepping (next to
    libtactile_mirror_c_tsan.so, found by its rpath)."""
    cc, cxx = cc_cxx()
    test = TESTS / "c" / "close_while_stepping.c"

    def make(d: Path) -> None:
        lib, lib_o, exe_o = d / "libtactile_mirror_c_tsan.so", d / "tm_capi.o", d / "close_while_stepping.o"
        run_all([
            [*launcher(), cxx, "-std=c++17", *TSAN_FLAGS, "-fPIC", "-Wno-psabi", "-I", str(SRC), "-c",
             str(SRC / "tm_capi.cpp"), "-o", str(lib_o)],
            [*launcher(), cc, "-std=c11", *TSAN_FLAGS, "-I", str(SRC), "-c", str(test), "-o", str(exe_o)],
        ])
        run([cxx, "-std=c++17", *TSAN_FLAGS, "-fPIC", "-shared", str(lib_o), "-o", str(lib), "-lpthread"])
        run([cc, *TSAN_FLAGS, str(exe_o), str(lib), "-Wl,-rpath," + str(d), "-lm", "-lpthread", "-o",
             str(d / "close_while_stepping")])

    return Spec("capi-tsan", make, "close_while_stepping",
                lambda: [compiler_id(cc), compiler_id(cxx), *TSAN_FLAGS], [SRC / "tm_capi.cpp", test], cost=31,
                needs_tsan=(cc, ".c") if cc else None)


if __name__ == "__main__":  # a look at the cache: python tests/_native_build.py
    print(cache_root())
    for p in sorted(cache_root().glob("*-*")):
        print(" ", p.name, "built" if _stamp(p) else "not built")
    sys.exit(0)
