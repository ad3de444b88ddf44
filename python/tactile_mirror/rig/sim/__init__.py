"""The simulated rig: a separate process with the FEM pad and the stage in real time, serving the
stage's serial line on a pseudo-terminal and the acquisition channels as clocked blocks."""
from __future__ import annotations

__all__: list[str] = []
