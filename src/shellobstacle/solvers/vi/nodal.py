"""The nodal constraint as bounds: one rotation per node (docs/model.md §5).

With the constraint ``g ≥ 0`` imposed at the Lagrange nodes (P1: the vertices; P2: the
vertices and edge midpoints), each constraint involves only the three unknowns of its node.
An orthogonal change of variables ``η_i = Q_i u_i`` per node (a Householder reflection whose
column ``k_i`` is ``c(x_i)/|c(x_i)|``; it leaves fixed Dirichlet components alone) turns it
into a lower bound on one rotated unknown, ``u_{i,k_i} ≥ ψ_i = −g(θ)(x_i) / |c(x_i)|``. With
the block-diagonal ``Q`` (a PETSc matrix, block size 3), ``K' = QᵀKQ`` and ``f' = Qᵀf`` the
obstacle problem is a bound-constrained quadratic program. The multiplier of a bound,
``λ_i = (K'u − f')_{i,k_i} / |c(x_i)|``, is the nodal contact force; divided by a lumped
mass it is a contact pressure.
"""

from __future__ import annotations

from mpi4py import MPI
from petsc4py import PETSc

import dolfinx
import dolfinx.la
import numpy as np
import ufl

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.points import lumped_mass_p2

__all__ = ["NodalConstraint", "nodal_rotations"]


def nodal_rotations(
    c: np.ndarray, free: np.ndarray, rel_tol: float = 1e-12
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthogonal 3×3 matrices ``Q_i`` whose column ``k_i`` is the free part of ``c_i``, normalized.

    ``Q_i`` is a Householder reflection (with column ``k_i`` negated where needed) acting only
    on the free (non-Dirichlet) components of node ``i``: ``Q_i e_j = e_j`` for every fixed
    component ``j``, so fixed unknowns stay fixed in the rotated basis, and
    ``c_i · (Q_i u) = |c_i^F| u_{k_i}`` (``c_i^F`` the free part of ``c_i``).

    Args:
        c: ``c_j(x_i) = a^j(x_i)·q``, shape ``(n, 3)``.
        free: which components of each node are free, shape ``(n, 3)``, bool.
        rel_tol: a node carries no constraint when ``|c_i^F| ≤ rel_tol · max_i |c_i|``.

    Returns:
        ``(Q, k, cn)``: ``Q`` of shape ``(n, 3, 3)``, ``k`` the index of the constrained rotated
        component (``-1`` where the node carries no constraint), and ``cn = |c_i^F|``.
    """
    n = c.shape[0]
    cf = np.where(free, c, 0.0)
    cn = np.linalg.norm(cf, axis=1)
    cmax = float(np.max(np.linalg.norm(c, axis=1), initial=0.0))
    constrained = cn > rel_tol * cmax if cmax > 0 else np.zeros(n, dtype=bool)
    Q = np.tile(np.eye(3), (n, 1, 1))
    k = np.full(n, -1, dtype=np.int64)
    idx = np.flatnonzero(constrained)
    if idx.size:
        m = np.arange(idx.size)
        nv = cf[idx] / cn[idx, None]
        kk = np.argmax(np.abs(nv) * free[idx], axis=1)
        s = np.where(nv[m, kk] >= 0, 1.0, -1.0)
        v = s[:, None] * nv  # n' = s n has n'_k = |n_k| > 0 ...
        v[m, kk] += 1.0  # ... so v = e_k + n' has |v|² = 2 + 2|n_k| ≥ 2 (no cancellation)
        H = np.eye(3)[None] - 2.0 * v[:, :, None] * v[:, None, :] / np.sum(v * v, 1)[:, None, None]
        H[m, :, kk] *= -s[:, None]  # H e_k = −n' = −s n, so the flipped column is n
        Q[idx] = H
        k[idx] = kk
    return Q, k, cn


class NodalConstraint:
    """The nodal data of one problem: gaps, rotations, bounds and the multiplier's space.

    The nodes are the Lagrange nodes of the displacement space: the vertices for P1, the
    vertices and edge midpoints for P2.

    Attributes:
        at_nodes: the obstacle's gap data at the owned nodes
            (:meth:`~shellobstacle.obstacle.Obstacle.at_points`).
        g0: ``g(θ)(x_i)``, the reference gap at the owned nodes.
        c: ``c_j(x_i) = ∂g/∂ζ_j`` (the plane's ``a^j(x_i)·q``), shape ``(n, 3)``.
        free: which components of each node are free (not Dirichlet), shape ``(n, 3)``.
        nodes: the owned nodes that carry a constraint.
        iB: their constrained rotated unknowns (local positions).
        psi: the bounds ``u_b ≥ ψ_b``.
        Q: the block-diagonal rotation (PETSc).
        multiplier, contact_pressure: scalar Functions on the nodes that
            :meth:`set_multiplier` fills.

    Raises:
        ValueError: a node whose displacement is fixed lies outside the admissible set.
    """

    def __init__(self, problem: PenalizedProblem) -> None:
        V = problem.V
        self.comm: MPI.Comm = problem.mesh.comm
        im = V.dofmap.index_map
        self.bs = bs = V.dofmap.index_map_bs
        self.n = n = im.size_local
        points = V.tabulate_dof_coordinates()[:n]
        eta = None  # a curved obstacle: its linearization at ζ̄ (problem.zeta_lin)
        if problem.zeta_lin is not None:
            eta = problem.zeta_lin.x.array[: n * bs].reshape(n, bs)
        self.at_nodes = problem.obstacle.at_points(problem.shell.surface, points, eta)
        self.g0, self.c = self.at_nodes.g0, self.at_nodes.c
        free = np.ones(n * bs, dtype=bool)
        for bc in problem.bcs:
            dofs, first_ghost = bc.dof_indices()
            free[dofs[:first_ghost]] = False
        self.free = free.reshape(n, bs)
        self.Qn, self.k, self.cn = nodal_rotations(self.c, self.free)
        self.nodes = np.flatnonzero(self.k >= 0)  # constrained nodes (local)
        bad = np.flatnonzero((self.k < 0) & (self.g0 < 0))
        if self.comm.allreduce(int(bad.size), op=MPI.SUM):
            raise ValueError(
                "a node whose displacement is fixed lies outside the admissible set "
                "(g(θ) < 0, below the plane): the obstacle problem has no admissible displacement"
            )
        self.iB = bs * self.nodes + self.k[self.nodes]
        self.psi = -self.g0[self.nodes] / self.cn[self.nodes]
        # block-diagonal Q (global block rows r0 … r0 + n − 1)
        r0 = im.local_range[0]
        cols = (bs * (r0 + np.arange(n)))[:, None, None] + np.arange(bs)[None, None, :]
        indices = np.broadcast_to(cols, (n, bs, bs)).reshape(-1).astype(PETSc.IntType)
        indptr = np.arange(0, n * bs * bs + 1, bs, dtype=PETSc.IntType)
        self.Q = PETSc.Mat().createAIJ(
            ((n * bs, PETSc.DETERMINE), (n * bs, PETSc.DETERMINE)),
            bsize=bs,
            csr=(indptr, indices, self.Qn.reshape(-1).astype(PETSc.ScalarType)),
            comm=self.comm,
        )
        self.Q.assemble()
        # the multiplier lives on the scalar space of the nodes (the collapsed first
        # component: dof j ↔ node parent[j] // 3)
        S, parent = V.sub(0).collapse()
        self._node_of = np.asarray(parent).reshape(-1) // bs
        self._n1 = S.dofmap.index_map.size_local
        self.multiplier = dolfinx.fem.Function(S, name="multiplier")
        self.contact_pressure = dolfinx.fem.Function(S, name="contact_pressure")
        if problem.disc.degree == 1:
            phi = ufl.TestFunction(S)
            mass = dolfinx.fem.assemble_vector(
                dolfinx.fem.form(phi * problem.G.sqrt_a * problem.dx_penalty)
            )
            mass.scatter_reverse(dolfinx.la.InsertMode.add)
            mass.scatter_forward()
            self.mass = mass.array.copy()  # lumped ∫ φ_j √a dy of the local P1 dofs
        else:
            self.mass = lumped_mass_p2(S, problem.G.sqrt_a)

    def node_masses(self) -> np.ndarray:
        """The lumped mass ``m_i`` of every owned node (:meth:`set_multiplier`'s divisor)."""
        m = np.zeros(self.n)
        m[self._node_of[: self._n1]] = self.mass[: self._n1]
        return m

    def gap(self, zeta: np.ndarray) -> np.ndarray:
        """``g_i = g(θ)(x_i) + c(x_i)·ζ(x_i)`` at the owned nodes (``zeta``: local dofs)."""
        return self.at_nodes.gap(zeta[: self.n * self.bs].reshape(self.n, self.bs))

    def constraint_force(self, lam: np.ndarray) -> np.ndarray:
        """``Bᵀλ`` on the owned dofs (row ``i`` of ``B`` is ``c(x_i)`` on node ``i``'s free
        unknowns)."""
        return (np.where(self.free, self.c, 0.0) * lam[:, None]).reshape(-1)

    def set_multiplier(self, lam: np.ndarray) -> None:
        """:attr:`multiplier` ← ``λ`` (owned nodes) and :attr:`contact_pressure` ←
        ``λ_i / m_i`` with the lumped mass ``m_i`` (P1: ``∫ φ_i √a dy``; P2:
        :func:`lumped_mass_p2`)."""
        lam_local = np.zeros(int(self._node_of.max(initial=-1)) + 1)
        lam_local[: self.n] = lam
        self.multiplier.x.array[: self._n1] = lam_local[self._node_of[: self._n1]]
        self.multiplier.x.scatter_forward()
        m = self.mass
        self.contact_pressure.x.array[:] = np.divide(
            self.multiplier.x.array, m, out=np.zeros_like(m), where=m > 0
        )
