"""The lab that builds and studies the runtime: detector build and training, evaluation,
the closed-loop experiment and its envelope, measuring run time against error, the
benchmark report and figures.

The lab imports only the runtime's public names (:mod:`tactile_mirror` and its
subpackages); the runtime never imports the lab. Each part loads on first use:

- :mod:`~tactile_mirror.lab.detector`: training (:func:`train_detector`), evaluation
  (:func:`evaluate`, :func:`roc`), the detector build and its studies, Figure 10;
- :mod:`~tactile_mirror.lab.loop`: the closed-loop experiment of the paper's section 4, the
  envelope over finger speeds, the Figs. 12/13 layout;
- :mod:`~tactile_mirror.lab.measure`: timing and error helpers shared by ``bench/`` and the report;
- :mod:`~tactile_mirror.lab.benchmark`: ``tactile-mirror bench``'s report;
- :mod:`~tactile_mirror.lab.plots`: contact-scene and Pareto figures;
- :mod:`~tactile_mirror.lab.testing`: known test signals.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from tactile_mirror._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    "train_detector": "detector", "evaluate": "detector", "roc": "detector",
}, submodules=("benchmark", "detector", "loop", "measure", "plots", "testing"))

if TYPE_CHECKING:
    from tactile_mirror.lab import benchmark, detector, loop, measure, plots, testing
    from tactile_mirror.lab.detector import evaluate, roc, train_detector
