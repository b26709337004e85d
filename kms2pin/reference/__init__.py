"""Slow, independent reference implementation of the thesis's kinematics and static update.

Pure SymPy + NumPy/SciPy (no Pinocchio), written from the equations of thesis §2.2-2.3
to check the fast path:

* :class:`SymbolicModel` / :func:`symbolic_model` -- C(q) = 0 (eq. 2.6, 2.13, 2.15 with
  the redundant rows of §2.3.2), row labels, the symbolic Jacobian C_q and numeric
  callables; numerical coordinate partitioning and B_di (eq. 2.24-2.32).
* :func:`forward_kinematics` -- eq. 2.12-2.16 walked in preorder.
* :func:`solve_equilibrium`, :func:`energy`, :func:`spring_forces`,
  :func:`equilibrium_residual` -- the static update of §2.3.3 (eq. 2.28, 2.33).
* :func:`generate_c`, :func:`generate_python` -- code generation as in §3.2.2.
"""

from __future__ import annotations

from .codegen import generate_c, generate_python
from .kinematics import forward_kinematics, joint_angles
from .rotations import alignment_matrix, axis_angle_matrix, matrix_to_quat, quat_to_matrix
from .statics import (
    ReferenceResult,
    aligned_targets,
    energy,
    equilibrium_residual,
    solve_equilibrium,
    spring_forces,
    stiffness_matrix,
)
from .symbolic import Partition, SymbolicModel, svd_pinv, symbolic_model

__all__ = [
    "Partition",
    "ReferenceResult",
    "SymbolicModel",
    "aligned_targets",
    "alignment_matrix",
    "axis_angle_matrix",
    "energy",
    "equilibrium_residual",
    "forward_kinematics",
    "generate_c",
    "generate_python",
    "joint_angles",
    "matrix_to_quat",
    "quat_to_matrix",
    "solve_equilibrium",
    "spring_forces",
    "stiffness_matrix",
    "svd_pinv",
    "symbolic_model",
]
