"""The mirror on a real rig: clocked acquisition in blocks, stage drivers that never block the
loop, and a simulated rig that stands in for the hardware.

Nothing here is imported by ``import tactile_mirror``; pyserial and nidaqmx (the optional
extras ``rig`` and ``nidaq``) load inside the drivers that use them.
"""
from __future__ import annotations

__all__: list[str] = []
