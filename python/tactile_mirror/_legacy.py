"""Old keyword-list calls mapped onto the option dataclasses that replaced them."""
from __future__ import annotations

import warnings


def legacy_arguments(func: str, params: tuple[str, ...], args: tuple, kwargs: dict, hint: str) -> dict:
    """Bind an old positional/keyword call of ``func`` to its parameter names, with a DeprecationWarning.

    ``params`` are the old parameters in their positional order; ``hint`` says how to call it now.
    Raises ``TypeError`` as Python would for too many positional arguments, an unknown keyword
    or a parameter given twice; the warning points at the caller of ``func``.
    """
    if len(args) > len(params):
        raise TypeError(f"{func} takes at most {len(params)} positional arguments")
    given = dict(zip(params, args))
    for k, v in kwargs.items():
        if k not in params:
            raise TypeError(f"{func} got an unexpected keyword argument {k!r}")
        if k in given:
            raise TypeError(f"{func} got multiple values for argument {k!r}")
        given[k] = v
    warnings.warn(f"{func} with keyword options is deprecated; pass {hint}", DeprecationWarning, stacklevel=4)
    return given
