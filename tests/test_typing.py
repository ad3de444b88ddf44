"""The package ships typed: ``py.typed``, a stub of the compiled core that matches the
module, and annotations that a type checker can use on the public API.

The stub is checked three ways: mypy's ``stubtest`` (every runtime name has a stub of
the same kind and the other way round), a comparison of each binding's signature as
pybind11 documents it (argument names, order and defaults) with the stub's, and mypy
run on a short typed use of the API (including calls that must be rejected).
"""
from __future__ import annotations

import ast
import contextlib
import importlib.util
import io
import os
import re
import site
import subprocess
import sys
import sysconfig
import textwrap
from pathlib import Path

import pytest
import tactile_mirror
from tactile_mirror import _core

PKG = Path(tactile_mirror.__file__).resolve().parent
STUB = PKG / "_core.pyi"
HAVE_MYPY = importlib.util.find_spec("mypy") is not None
needs_mypy = pytest.mark.skipif(not HAVE_MYPY, reason="mypy is not installed (it comes with the 'test' extra)")

# Third-party packages that the library imports but the checks here do not need to
# analyse (slow, or without type information).
_SKIP = "matplotlib.*,mpl_toolkits.*,scipy.*,skfem.*,tqdm.*,dask.*,distributed.*,cffi.*,hypothesis.*"


def test_public_names_resolve():
    assert len(set(tactile_mirror.__all__)) == len(tactile_mirror.__all__)
    missing = [name for name in tactile_mirror.__all__ if not hasattr(tactile_mirror, name)]
    assert not missing


def test_py_typed_and_stub_ship():
    # PKG is the installed package (or the source tree for an editable install).
    assert (PKG / "py.typed").is_file()
    assert STUB.is_file()
    assert Path(_core.__file__).resolve().parent.name == "tactile_mirror"


# ---- stub against the runtime signatures --------------------------------------------------

def _split_top(s: str) -> list[str]:
    """Split on commas outside brackets and quotes."""
    parts, depth, quote, cur = [], 0, "", []
    for ch in s:
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    if "".join(cur).strip():
        parts.append("".join(cur).strip())
    return parts


def _runtime_params(name: str, doc: str | None) -> list[tuple[str, str]]:
    """(name, repr of default or "") of each argument but self, from pybind11's docstring."""
    assert doc, f"{name} has no docstring (pybind11 puts the signature there)"
    first = doc.lstrip().splitlines()[0]
    m = re.match(rf"{re.escape(name)}\((.*)\)\s*->", first)
    assert m, f"cannot read the signature of {name} from {first!r} (overloaded binding?)"
    out = []
    for p in _split_top(m.group(1)):
        if p in ("*", "/"):
            out.append((p, ""))
            continue
        pname, _, rest = p.partition(":")
        default = rest.split(" = ", 1)[1].strip() if " = " in rest else ""
        if pname.strip() != "self":
            out.append((pname.strip(), repr(ast.literal_eval(default)) if default else ""))
    return out


def _stub_params(fn: ast.FunctionDef) -> list[tuple[str, str]]:
    a = fn.args
    pos = a.posonlyargs + a.args
    defaults = [None] * (len(pos) - len(a.defaults)) + list(a.defaults)
    out = [(p.arg, repr(ast.literal_eval(d)) if d is not None else "") for p, d in zip(pos, defaults)]
    if a.posonlyargs:
        out.insert(len(a.posonlyargs), ("/", ""))
    if a.kwonlyargs:
        out.append(("*", ""))
        out += [(p.arg, repr(ast.literal_eval(d)) if d is not None else "")
                for p, d in zip(a.kwonlyargs, a.kw_defaults)]
    return [p for p in out if p[0] != "self"]


def _decorators(fn: ast.FunctionDef) -> set[str]:
    return {ast.unparse(d) for d in fn.decorator_list}


def _stub_tree():
    """{class or "": {name: [FunctionDef, ...]}} with stub-only bases merged in."""
    tree = ast.parse(STUB.read_text())
    classes: dict[str, tuple[list[str], dict[str, list[ast.FunctionDef]]]] = {}
    module: dict[str, list[ast.FunctionDef]] = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            module.setdefault(node.name, []).append(node)
        elif isinstance(node, ast.ClassDef):
            bases = [ast.unparse(b.value if isinstance(b, ast.Subscript) else b) for b in node.bases]
            members: dict[str, list[ast.FunctionDef]] = {}
            for item in node.body:
                if isinstance(item, ast.FunctionDef):
                    members.setdefault(item.name, []).append(item)
            classes[node.name] = (bases, members)

    def resolved(name):
        bases, own = classes[name]
        merged = {}
        for b in reversed(bases):
            if b in classes:
                merged.update(resolved(b))
        merged.update(own)
        return merged

    return {"": module, **{c: resolved(c) for c in classes}}


def _runtime_members():
    """(qualified name, stub class or "", member name, runtime object) of every binding."""
    for name, obj in vars(_core).items():
        if isinstance(obj, type):
            for mname, member in vars(obj).items():
                if mname == "__init__" or not mname.startswith("_"):
                    yield f"{name}.{mname}", name, mname, member
        elif callable(obj) and not name.startswith("__"):
            yield name, "", name, obj


def test_stub_signatures_match_the_bindings():
    stub = _stub_tree()
    problems = []
    for qual, cls, name, obj in _runtime_members():
        defs = stub.get(cls, {}).get(name)
        if not defs:
            problems.append(f"{qual}: not in the stub")
            continue
        if isinstance(obj, property):
            getters = [d for d in defs if "property" in _decorators(d)]
            setters = [d for d in defs if f"{name}.setter" in _decorators(d)]
            if not getters:
                problems.append(f"{qual}: a property at run time, not in the stub")
            if bool(setters) != (obj.fset is not None):
                problems.append(f"{qual}: {'has' if obj.fset else 'has no'} setter at run time, "
                                f"the stub {'has' if setters else 'has none'}")
            continue
        runtime = _runtime_params(name, obj.__doc__)
        overloads = [d for d in defs if "overload" in _decorators(d)] or defs
        for d in overloads:
            params = _stub_params(d)
            if len(overloads) > 1:
                # Overloads may narrow kinds and drop defaults (e.g. Literal[True] flags), but
                # keep the names in order and never give a default the binding does not have.
                names = [p for p, _ in params if p not in "*/"]
                want = [p for p, _ in runtime if p not in "*/"]
                rt = dict(runtime)
                if names != want or any(dflt and dflt != rt[p] for p, dflt in params if p not in "*/"):
                    problems.append(f"{qual} (overload, line {d.lineno}): {params} vs binding {runtime}")
            elif params != runtime:
                problems.append(f"{qual}: stub {params} vs binding {runtime}")
        if len(overloads) > 1 and not any(_stub_params(d) == runtime for d in overloads):
            problems.append(f"{qual}: no overload has the binding's signature {runtime}")
    assert not problems, "\n".join(problems)


def test_signature_check_sees_drift():
    bad = ast.parse("def f(self, n_iter: int = 5, *, mode: str = 'simd') -> float: ...").body[0]
    assert _stub_params(bad) == [("n_iter", "5"), ("*", ""), ("mode", "'simd'")]
    doc = "time_step_ns(self: X, n_iter: typing.SupportsInt = 1000000, mode: str = 'a,b') -> float\n"
    assert _runtime_params("time_step_ns", doc) == [("n_iter", "1000000"), ("mode", "'a,b'")]


# ---- mypy -------------------------------------------------------------------------------

def _mypy_env() -> dict[str, str]:
    """mypy finds an installed package through site-packages (py.typed); a source tree
    (editable install, found through an import hook) has to be on MYPYPATH."""
    env = dict(os.environ)
    env.pop("MYPYPATH", None)
    paths = sysconfig.get_paths()
    installed = [paths["purelib"], paths["platlib"], *site.getsitepackages()]
    if site.ENABLE_USER_SITE:
        installed.append(site.getusersitepackages())
    if str(PKG.parent) not in {str(Path(p).resolve()) for p in installed}:
        env["MYPYPATH"] = str(PKG.parent)
    return env


def _run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, env=_mypy_env(), capture_output=True,
                          text=True, timeout=300, check=False)


@needs_mypy
def test_stubtest(tmp_path):
    cfg = tmp_path / "mypy.ini"
    # Only the stub and numpy need analysing; the package's __init__ (which mypy reads as
    # the stub's parent) would pull in the whole library and its dependencies.
    cfg.write_text("[mypy]\nfollow_imports = skip\n[mypy-numpy,numpy.*,typing_extensions]\nfollow_imports = normal\n")
    from mypy import stubtest

    flags = ["--concise", "--mypy-config-file", str(cfg)]
    try:  # stub-only classes must be marked @type_check_only (option of newer mypy versions)
        with contextlib.redirect_stderr(io.StringIO()):
            stubtest.parse_options(["--strict-type-check-only", "m"])
        flags.append("--strict-type-check-only")
    except SystemExit:
        pass
    r = _run(["mypy.stubtest", "tactile_mirror._core", *flags], tmp_path)
    lines = [ln for ln in r.stdout.splitlines() if ln.strip()]
    # pybind11 classes have pybind11's metaclass, which a stub cannot name.
    real = [ln for ln in lines if not re.fullmatch(r"tactile_mirror\._core\.\w+ is inconsistent, metaclass differs", ln)]
    assert not real and r.returncode in (0, 1) and not r.stderr.strip(), r.stdout + r.stderr
    classes = [n for n, o in vars(_core).items() if isinstance(o, type)]
    assert len(lines) == len(classes), r.stdout  # it did check every class


USAGE = '''
from __future__ import annotations

from typing import Literal

import numpy as np
import numpy.typing as npt
from typing_extensions import assert_type

import tactile_mirror as tm
from tactile_mirror import _core

sos = tm.differentiator_sos(10_000.0, order=2)
assert_type(sos, np.ndarray)
assert_type(tm.sosfilt(sos, np.zeros(64)), np.ndarray)
y, zf = tm.sosfilt(sos, np.zeros(64), zi=np.zeros((sos.shape[0], 2)))
f = tm.SosFilter(sos, channels=2, dtype=np.float32, structure="delta")
assert_type(f.process(np.zeros((2, 8))), np.ndarray)
assert_type(tm.simd_path(), str)
assert_type(tm.roundoff_bound(sos, np.ones(16)), float)
rate, rate2 = tm.estimate_stress_rate(np.zeros((2, 64)), None, tm.PVDFCircuit(), 10_000.0)
assert_type(rate, np.ndarray)
assert_type(tm.PVDFCircuit().simulate(np.zeros((3, 64)), 10_000.0, noise=(1e-3, 2e-3), seed=1),
            tuple[np.ndarray, np.ndarray])
assert_type(tm.scenes.paper("fig7", noise=1e-3), tm.Scene)


def kernels(w: npt.NDArray[np.float64], x32: npt.NDArray[np.float32], x64: npt.NDArray[np.float64]) -> None:
    k = _core.JordanMLPf32(w, w, w, w, w, w, n_instances=3, activation="fast")
    assert_type(k.step(x32), npt.NDArray[np.float32])
    assert_type(k.run(x32), npt.NDArray[np.float32])
    assert_type(k.dtype, np.dtype[np.float32])
    k.activation = "exact"
    k.state = x32
    k.set_simd_path("avx2")
    assert_type(k.time_step_ns(1000, mode="scalar"), float)
    assert_type(_core.JordanMLPf64(w, w, w, w, w, w, 1).step_one(0, x64), npt.NDArray[np.float64])
    assert_type(_core.detector_sigmoid(x32, "exact", "generic"), npt.NDArray[np.float32])
    assert_type(_core.detector_sigmoid(x64), npt.NDArray[np.float64])
    c = _core._SosCascade32(w, 2, np.zeros(1, np.uint8))
    yb, bad_t, bad_c = c.process(x32)
    assert_type(bad_t, int)
    assert_type(c.step([0.0, 1.0]), npt.NDArray[np.float32])
    k.step(x64)  # type: ignore[arg-type]
    k.activation = "slow"  # type: ignore[assignment]
    k.time_step_ns(mode="vector")  # type: ignore[arg-type]
    _core.detector_sigmoid(x32, path="neon")  # type: ignore[call-overload]


def pipeline(p: _core._MirrorPipelineF64F32, x: npt.NDArray[np.float64]) -> None:
    assert_type(p.step(x[0], out=np.empty(p.n_outputs)), float)
    (out,) = p.process_block(x)
    out, feats = p.process_block(x, features=True)
    out, acc = p.process_block(x, accepted=True)
    out, feats, acc = p.process_block(x, True, True)
    assert_type(acc, npt.NDArray[np.bool_])
    assert_type(p.status["ticks"], int)
    assert_type(p.status["fault"], bool)
    assert_type(p.controller["kind"], Literal["none", "paper", "velocity"])
    assert_type(p.controller_state["position"], float)
    assert_type(p.detector_dtype, np.dtype[np.float32])
    p.reset(0.0)
    p.status["tick"]  # type: ignore[typeddict-item]
    out, feats = p.process_block(x)  # type: ignore[misc]
'''


@needs_mypy
def test_mypy_on_typed_usage(tmp_path):
    (tmp_path / "usage.py").write_text(textwrap.dedent(USAGE))
    cfg = tmp_path / "mypy.ini"
    cfg.write_text(f"[mypy]\nfollow_imports = silent\nignore_missing_imports = True\nwarn_unused_ignores = True\n"
                   f"strict_equality = True\n[mypy-{_SKIP}]\nfollow_imports = skip\n")
    r = _run(["mypy", "--config-file", str(cfg), "--cache-dir", str(tmp_path / "cache"), "--no-error-summary",
              "usage.py"], tmp_path)
    assert r.returncode == 0 and not r.stdout.strip(), r.stdout + r.stderr
