"""The package's shape: its layers (import-linter contracts in pyproject.toml), no import
circles, no private name across modules, and an import that loads numpy and the compiled core
only."""
from __future__ import annotations

import ast
import json
import pathlib
import subprocess
import sys

import pytest
import tactile_mirror

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = pathlib.Path(tactile_mirror.__file__).resolve().parent


def _modules(folder: pathlib.Path, prefix: str):
    """(module name, path, is a package __init__) of every Python file below ``folder``."""
    for path in sorted(folder.rglob("*.py")):
        rel = path.relative_to(folder).with_suffix("")
        parts = [prefix, *rel.parts] if prefix else list(rel.parts)
        is_init = parts[-1] == "__init__"
        if is_init:
            parts = parts[:-1]
        yield ".".join(parts), path, is_init


def _imports(path: pathlib.Path, module: str, is_init: bool):
    """(line, imported module, imported name or None) of every import in a file, relative
    imports resolved against ``module``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module if is_init else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, None
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:
                yield node.lineno, base, alias.name


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def test_layer_contracts_hold():
    """Every contract of [tool.importlinter] in pyproject.toml is kept (none ignores an import)."""
    importlinter = pytest.importorskip("importlinter.cli")
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    assert "ignore_imports" not in text
    assert importlinter.lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True) == 0


def test_no_import_circles():
    """No module of the package imports itself through others (strongly connected
    components of the static import graph, function-level imports included)."""
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("tactile_mirror", exclude_type_checking_imports=True)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def connect(v: str) -> None:  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for module in sorted(graph.modules):
        if module not in index:
            connect(module)
    assert circles == []


def test_no_private_name_crosses_a_module():
    """No module imports a ``_name`` from another module, in the package or in bench/; the
    package-internal modules (``tactile_mirror.checks``, ``_io``, ...) are imported only by the
    runtime, never by the lab, the command line or a study."""
    crossings = []
    sources = [*_modules(PACKAGE, "tactile_mirror")]
    if (ROOT / "bench").is_dir():
        sources += [(f"bench.{m}", p, i) for m, p, i in _modules(ROOT / "bench", "")]
    for module, path, is_init in sources:
        outside_runtime = module.startswith(("tactile_mirror.lab", "tactile_mirror.cli", "bench."))
        for line, imported, name in _imports(path, module, is_init):
            where = f"{path.name}:{line}"
            if name is not None and _private(name) and not (name == "_core" and not outside_runtime):
                if imported.startswith("tactile_mirror") or module.startswith("bench."):
                    crossings.append(f"{where} imports {name} from {imported}")
            internal = any(_private(part) for part in imported.split(".")[1:])
            if outside_runtime and imported.startswith("tactile_mirror") and internal \
                    and imported != "tactile_mirror._lazy":
                crossings.append(f"{where} imports the package-internal {imported}")
    assert crossings == []


def _loaded_after(code: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", f"{code}\nimport json, sys\nprint(json.dumps(sorted(sys.modules)))"],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.splitlines()[-1])


HEAVY = ("scipy.signal", "scipy.optimize", "scipy.sparse", "skfem", "matplotlib", "tqdm", "tactile_mirror.lab")


def _heavy(modules: list[str]) -> list[str]:
    return sorted(m for m in modules if m.startswith(HEAVY))


def test_import_loads_numpy_and_the_core_only():
    loaded = _loaded_after("import tactile_mirror")
    assert _heavy(loaded) == [] and "scipy" not in loaded
    ours = sorted(m for m in loaded if m.startswith("tactile_mirror"))
    assert ours == ["tactile_mirror", "tactile_mirror._core", "tactile_mirror._lazy"]


def test_the_runtime_path_loads_no_study_and_no_designer():
    """Touching the runtime's real-time objects loads no scipy.signal/optimize/sparse,
    scikit-fem, matplotlib or lab module."""
    loaded = _loaded_after("import tactile_mirror as tm\ntm.MirrorPipeline\ntm.SlipDetector.default()\n"
                           "tm.StressRateEstimator\ntm.LoopRunner\ntm.Recording")
    assert _heavy(loaded) == []


def test_names_stay_one_attribute_away():
    import tactile_mirror as tm

    assert tm.sosfilt is tm.filters.sosfilt and tm.MirrorPipeline is tm.pipeline.MirrorPipeline
    assert set(tm.__all__) <= set(dir(tm))
    for name in tm.__all__:
        getattr(tm, name)
    with pytest.raises(AttributeError, match="no_such_name"):
        tm.no_such_name  # noqa: B018
    assert not hasattr(tm, "train_detector") and not hasattr(tm, "evaluate")


def test_lazy_names_are_what_they_say_whatever_was_imported_first():
    """After every module of the package is imported (which sets each submodule as an
    attribute of its package), no public name of a package is a module it should not be, and
    no submodule shares its name with a name it defines (the package attribute would be one
    or the other by import order)."""
    code = """
import importlib, importlib.util, inspect, json, pkgutil
import tactile_mirror
bad = []
for info in pkgutil.walk_packages(tactile_mirror.__path__, "tactile_mirror."):
    if (importlib.util.find_spec(info.name).origin or "").endswith(".py"):
        importlib.import_module(info.name)
for name in ("tactile_mirror", "tactile_mirror.contact", "tactile_mirror.loop", "tactile_mirror.detector",
             "tactile_mirror.lab", "tactile_mirror.lab.detector", "tactile_mirror.pipeline"):
    package = importlib.import_module(name)
    for attr in package.__all__:
        value = getattr(package, attr)
        submodule = f"{name}.{attr}"
        if importlib.util.find_spec(submodule) is None:
            if inspect.ismodule(value):
                bad.append(f"{submodule} is the module {value.__name__}")
        elif hasattr(importlib.import_module(submodule), attr):
            bad.append(f"{submodule} is a module and defines {attr}: one hides the other")
print(json.dumps(bad))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out.splitlines()[-1]) == []
