"""Figures (lab.plots, lab.detector.figures, lab.loop.figures): their arguments are checked
before anything runs or is drawn."""
from __future__ import annotations

import os

import numpy as np
import pytest


def test_figures_refuse_a_ridge_the_result_has_not(tmp_path):
    """A ridge index out of range was an IndexError deep inside (or, negative, another ridge
    silently); now a ValueError naming ``ridge``, before anything runs or is drawn."""
    from types import SimpleNamespace

    import matplotlib.pyplot as plt
    from tactile_mirror.lab.detector.figures import figure10, figure10_data
    from tactile_mirror.lab.loop.figures import loop_figure
    from tactile_mirror.lab.plots import contact_scene_figure

    n = 50
    contact = SimpleNamespace(v_out=np.zeros((2, 2, n)), u_out=np.zeros((2, 2, n)), slip_fraction=np.zeros((2, n)))
    ready = SimpleNamespace(features=np.zeros((2, 4, n)), fs=1000.0, t=np.arange(n) / 1000.0)
    loop = SimpleNamespace(log={"v_out": np.zeros((2, 2, n))})
    figures = len(plt.get_fignums())
    for ridge in (2, -1, 99):
        with pytest.raises(ValueError, match=r"ridge must be in \[0, 1\]"):
            contact_scene_figure(contact, ridge=ridge)
        with pytest.raises(ValueError, match="ridge"):
            figure10_data(object(), ready, ridge=ridge)  # (the detector is never reached)
        with pytest.raises(ValueError, match="ridge"):
            figure10(object(), ready, ready, ridge=ridge)
        with pytest.raises(ValueError, match="ridge"):
            loop_figure(loop, tmp_path / "f.png", closed=False, ridge=ridge)
    with pytest.raises(TypeError, match="ridge"):
        contact_scene_figure(contact, ridge=1.0)
    assert len(plt.get_fignums()) == figures and not os.listdir(tmp_path)  # nothing drawn, nothing written
