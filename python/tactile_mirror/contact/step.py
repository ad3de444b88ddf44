"""What one quasi-static step of a ridge answers, in both backends of
:class:`~tactile_mirror.contact.solver.ContactSolver`: the node statuses
(``OPEN``, ``STICK``, ``SLIP``), the result :class:`ContactStep`, and
:class:`ContactConvergenceError` for a step that cannot be solved.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["OPEN", "SLIP", "STICK", "ContactConvergenceError", "ContactStep"]

#: Node statuses: not touching the plate, touching and stuck, touching and sliding.
OPEN, STICK, SLIP = 0, 1, 2


class ContactConvergenceError(RuntimeError):
    """The semismooth Newton iteration did not reach its tolerance."""


@dataclass
class ContactStep:
    """Result of one quasi-static step of one ridge."""

    forces: np.ndarray  # (2n,) nodal forces on the ridge f = (f_y, f_z), N/m
    displacement: np.ndarray  # (2n,) surface displacements (u_y, u_z), m
    state: np.ndarray  # (n,) OPEN / STICK / SLIP
    slip_fraction: float  # share of the contact length that slips, 0..1
    iterations: int

    @property
    def in_contact(self) -> bool:
        """Some node touches the plate."""
        return bool(np.any(self.state != OPEN))

    @property
    def gross_slip(self) -> bool:
        """Every node in contact slips."""
        return self.in_contact and not np.any(self.state == STICK)
