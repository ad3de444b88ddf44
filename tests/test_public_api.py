"""A snapshot of the public API: every public module's ``__all__``, each name's kind and
signature, and the public methods of its classes. A change to any of them fails this test
until the snapshot is written again, so that a move or a rename is made on purpose (and goes
into CHANGELOG.md):

    python tests/test_public_api.py --update
"""
from __future__ import annotations

import importlib
import importlib.util
import inspect
import pathlib
import pkgutil
import re
import sys

import tactile_mirror

SNAPSHOT = pathlib.Path(__file__).with_name("public_api.txt")


def _public_modules() -> list[str]:
    names = ["tactile_mirror"]
    for info in pkgutil.walk_packages(tactile_mirror.__path__, "tactile_mirror."):
        origin = importlib.util.find_spec(info.name).origin or ""
        if origin.endswith(".py") and not any(part.startswith("_") for part in info.name.split(".")):
            names.append(info.name)  # (the C ABI's shared library sits beside the modules: skipped)
    return sorted(names)


def _signature(obj) -> str:
    try:
        text = str(inspect.signature(obj))
    except (TypeError, ValueError):
        return "(...)"
    # a frozenset default prints in hash order, which changes from run to run: sort it
    return re.sub(r"frozenset\(\{([^}]*)\}\)", lambda m: "frozenset({%s})" % ", ".join(sorted(m.group(1).split(", "))),
                  text)


def _describe(qualname: str, obj) -> list[str]:
    if inspect.ismodule(obj):
        return [f"{qualname}: module {obj.__name__}"]
    if inspect.isclass(obj):
        lines = [f"{qualname}: class{_signature(obj)}"]
        for name, member in sorted(vars(obj).items()):
            if name.startswith("_") and name != "__init__":
                continue
            if isinstance(member, property):
                lines.append(f"{qualname}.{name}: property")
            elif isinstance(member, (staticmethod, classmethod)):
                lines.append(f"{qualname}.{name}: {type(member).__name__}{_signature(member.__func__)}")
            elif inspect.isfunction(member):
                lines.append(f"{qualname}.{name}: method{_signature(member)}")
        return lines
    if callable(obj):
        return [f"{qualname}: function{_signature(obj)}"]
    return [f"{qualname}: {type(obj).__name__}"]


def api_lines() -> list[str]:
    lines = []
    for module_name in _public_modules():
        module = importlib.import_module(module_name)
        for name in sorted(getattr(module, "__all__", ())):
            lines += _describe(f"{module_name}.{name}", getattr(module, name))
    return lines


def test_public_api_matches_the_snapshot():
    expected = SNAPSHOT.read_text(encoding="utf-8").splitlines()
    actual = api_lines()
    missing = sorted(set(expected) - set(actual))
    added = sorted(set(actual) - set(expected))
    assert (missing, added) == ([], []), "the public API changed: run python tests/test_public_api.py --update"


def test_every_public_module_lists_its_names():
    without = [m for m in _public_modules() if not hasattr(importlib.import_module(m), "__all__")]
    assert without == []


if __name__ == "__main__":
    if sys.argv[1:] != ["--update"]:
        sys.exit(__doc__)
    SNAPSHOT.write_text("\n".join(api_lines()) + "\n", encoding="utf-8")
