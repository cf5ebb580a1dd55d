"""The paper's cap pushed onto the plane on a square mesh: the small problem of the output tests
(ParaView files, 3D pictures)."""

from __future__ import annotations

from mpi4py import MPI

import dolfinx.mesh
import numpy as np
from conftest import make_paper_shell

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.spec import Discretization


def cap_on_square(half: float, n: int, degree: int = 1, kappa: float = 1e-3) -> PenalizedProblem:
    """The cap (R = 1, θ₃ offset 0.85) under the paper's load on ``[-half, half]²`` with ``n × n``
    squares (each split in two), compiled at ``κ``: the vertex penalty for P1, Gauss points
    for P2, quadrature degree 4."""
    mesh = dolfinx.mesh.create_rectangle(
        MPI.COMM_WORLD, [np.array([-half, -half]), np.array([half, half])], [n, n]
    )
    shell = make_paper_shell()
    quadrature = "vertex" if degree == 1 else "gauss"
    disc = Discretization(degree=degree, penalty_quadrature=quadrature, quadrature_degree=4)
    return PenalizedProblem(shell, mesh, disc, kappa=kappa)
