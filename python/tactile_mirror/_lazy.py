"""Lazy attributes of a package (PEP 562), in the scientific-Python pattern (SPEC 1).

A package lists its public names and the submodule that defines each; a name's submodule
is imported when the name is first read, so importing the package costs only what its own
``__init__`` imports. Type checkers read the package's ``if TYPE_CHECKING:`` imports.
"""
from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterable, Mapping


def attach(package: str, names: Mapping[str, str], submodules: Iterable[str] = ()
           ) -> tuple[Callable[[str], object], Callable[[], list[str]], list[str]]:
    """``(__getattr__, __dir__, __all__)`` for ``package``.

    ``names`` maps each public name to the submodule (relative to ``package``) that defines
    it; ``submodules`` are submodules reachable as attributes. A name read once is stored in
    the package's namespace, so later reads do not come here.
    """
    names = dict(names)
    submodules = tuple(submodules)
    public = sorted({*names, *submodules})

    def __getattr__(name: str):
        if name in submodules:
            return importlib.import_module(f"{package}.{name}")
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return list(public)

    return __getattr__, __dir__, public
