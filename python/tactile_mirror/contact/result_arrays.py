"""A :class:`~tactile_mirror.contact.simulation.SimulationResult` as plain arrays and JSON, and back.

What a result store keeps of a simulated scene (:class:`tactile_mirror.engine.ResultStore`):
its arrays (numbers only, no objects) and its scalars as a JSON dict. The scene itself is
not kept: the store names a file by the scene's content, and a result read back gets the
scene it was asked for. :func:`result_bounds` bounds every array by the scene (its samples,
ridges, field times), so a file is checked before its data is read, and
:func:`result_from_arrays` refuses arrays that do not fit the scene.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tactile_mirror._npzfile import Member

if TYPE_CHECKING:
    from tactile_mirror.contact.simulation import SimulationResult
    from tactile_mirror.scenes import Scene

__all__ = ["MAX_ELEMENTS", "MAX_NODES", "MAX_STRIPS", "result_arrays", "result_bounds", "result_from_arrays"]

#: Bounds of a stored result's mesh sizes (a ridge's surface nodes, strips, elements):
#: far above any mesh the contact model makes (hundreds of nodes, thousands of elements).
MAX_NODES = 100_000
MAX_STRIPS = 64
MAX_ELEMENTS = 10_000_000

# the arrays of a result, with their (kind, ndim); their shapes are checked against the scene
_ARRAYS = {"t": ("f", 1), "plate_y": ("f", 1), "indent": ("f", 1), "stress": ("f", 4), "v_out": ("f", 3),
           "u_out": ("f", 3), "slip_fraction": ("f", 2), "ridge_slip_time": ("f", 1), "force_y": ("f", 1),
           "force_z": ("f", 1), "node_state": ("i", 3), "node_position": ("f", 4)}
_SCALARS = ("fs", "slip_time", "newton_iterations", "stepping", "backend", "solves", "events")


def result_arrays(result: SimulationResult) -> tuple[dict[str, np.ndarray], dict]:
    """``(arrays, meta)``: the result's arrays (those it has) and stress fields
    (``field_times`` (k,) s, ``field_stress`` (k, 4, n_elements) Pa, ``field_centroids``
    (k, 2, n_elements) m), and its scalars as a JSON dict."""
    arrays = {name: np.asarray(getattr(result, name)) for name in _ARRAYS if getattr(result, name) is not None}
    if result.fields:
        times = sorted(result.fields)
        arrays["field_times"] = np.array(times, dtype=float)
        arrays["field_stress"] = np.stack([np.asarray(result.fields[t][0]) for t in times])
        arrays["field_centroids"] = np.stack([np.asarray(result.fields[t][1]) for t in times])
    meta = {name: getattr(result, name) for name in _SCALARS}
    meta["fs"] = float(meta["fs"])
    if meta["slip_time"] is not None:
        meta["slip_time"] = float(meta["slip_time"])
    for name in ("newton_iterations", "solves", "events"):
        meta[name] = int(meta[name])
    return arrays, meta


def result_bounds(scene: Scene) -> dict[str, Member]:
    """The bounds of the arrays of ``scene``'s result (for a bounded read)."""
    n, ridges, k = scene.n_samples, int(scene.n_ridges), len(scene.field_times)
    bounds = {"t": (n,), "plate_y": (n,), "indent": (n,), "stress": (ridges, MAX_STRIPS, 3, n),
              "v_out": (ridges, MAX_STRIPS, n), "u_out": (ridges, MAX_STRIPS, n), "slip_fraction": (ridges, n),
              "ridge_slip_time": (ridges,), "force_y": (n,), "force_z": (n,), "node_state": (ridges, MAX_NODES, n),
              "node_position": (ridges, 2, MAX_NODES, n)}
    members = {name: Member(kind, ndim, bounds[name], required=False) for name, (kind, ndim) in _ARRAYS.items()}
    members["field_times"] = Member("f", 1, (k,), required=False)
    members["field_stress"] = Member("f", 3, (k, 4, MAX_ELEMENTS), required=False)
    members["field_centroids"] = Member("f", 3, (k, 2, MAX_ELEMENTS), required=False)
    return members


def _wanted(scene: Scene) -> set:
    outs = scene.outputs
    wanted = {"t", "plate_y", "indent", "ridge_slip_time"}
    if outs & {"stress", "signals"}:
        wanted.add("stress")
    if "signals" in outs:
        wanted |= {"v_out", "u_out"}
    if "slip" in outs:
        wanted.add("slip_fraction")
    if "forces" in outs:
        wanted |= {"force_y", "force_z"}
    if "state" in outs:
        wanted |= {"node_state", "node_position"}
    return wanted


def result_from_arrays(scene: Scene, arrays: dict[str, np.ndarray], meta: dict) -> SimulationResult:
    """The :class:`SimulationResult` of ``scene`` from :func:`result_arrays`' output.

    Raises ``ValueError`` (or ``KeyError``, ``TypeError``) when the arrays or the scalars
    do not fit the scene: an array the scene asks for missing or one it does not ask for
    present, shapes that disagree with each other or with the scene, a scalar of the
    wrong type.
    """
    from tactile_mirror.contact.simulation import SimulationResult

    present = {name for name in _ARRAYS if name in arrays}
    wanted = _wanted(scene)
    if present != wanted:
        raise ValueError(f"arrays {sorted(present ^ wanted)} do not fit the scene's outputs")
    n = arrays["t"].shape[0]
    ridges = int(scene.n_ridges)
    strips = arrays["stress"].shape[1] if "stress" in arrays else None
    nodes = arrays["node_state"].shape[1] if "node_state" in arrays else None
    shapes = {"t": (n,), "plate_y": (n,), "indent": (n,), "stress": (ridges, strips, 3, n),
              "v_out": (ridges, strips, n), "u_out": (ridges, strips, n), "slip_fraction": (ridges, n),
              "ridge_slip_time": (ridges,), "force_y": (n,), "force_z": (n,), "node_state": (ridges, nodes, n),
              "node_position": (ridges, 2, nodes, n)}
    for name in present:
        if arrays[name].shape != shapes[name]:
            raise ValueError(f"{name} has shape {arrays[name].shape}, expected {shapes[name]}")
    if not 1 <= n <= scene.n_samples:
        raise ValueError(f"t has {n} samples, the scene at most {scene.n_samples}")
    fields = {}
    if "fields" in scene.outputs and scene.field_times and "field_times" in arrays:
        # (no field arrays: a run that stopped before the first field time has none)
        times, stress, centroids = arrays["field_times"], arrays["field_stress"], arrays["field_centroids"]
        if stress.shape[0] != times.shape[0] or centroids.shape != (times.shape[0], 2, stress.shape[2]):
            raise ValueError("the stress fields' arrays disagree in shape")
        if not set(times.tolist()) <= set(map(float, scene.field_times)):
            raise ValueError("the stress fields are at times the scene does not ask for")
        fields = {float(t): (stress[i], centroids[i]) for i, t in enumerate(times)}
    elif any(name in arrays for name in ("field_times", "field_stress", "field_centroids")):
        raise ValueError("stress fields present, the scene asks for none")
    fs = meta["fs"]
    if not isinstance(fs, float) or fs != float(scene.fs):
        raise ValueError(f"fs {fs!r} is not the scene's {scene.fs!r}")
    slip_time = meta["slip_time"]
    if slip_time is not None and not isinstance(slip_time, float):
        raise TypeError(f"slip_time must be a number or null, got {slip_time!r}")
    counts = {}
    for name in ("newton_iterations", "solves", "events"):
        if isinstance(meta[name], bool) or not isinstance(meta[name], int):
            raise TypeError(f"{name} must be an integer, got {meta[name]!r}")
        counts[name] = meta[name]
    for name in ("stepping", "backend"):
        if not isinstance(meta[name], str):
            raise TypeError(f"{name} must be a text, got {meta[name]!r}")
    return SimulationResult(scene=scene, fs=fs, slip_time=slip_time, fields=fields, stepping=meta["stepping"],
                            backend=meta["backend"], **counts, **{name: arrays[name] for name in present})
