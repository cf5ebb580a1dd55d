"""The bending part alone: C⁰ interior penalty P2 against the Hellan–Herrmann–Johnson mixed form.

A clamped unit-square plate (biharmonic, D = 1, uniform load 1; the centre deflection is
0.00126532, Timoshenko & Woinowsky-Krieger, table 35) on ``n × n`` squares split in two, solved
by MUMPS' LDLᵀ of the whole matrix:

- ``c0ip``: ``w`` in P2 with the symmetric interior-penalty facet terms (σ = 8), the
  discretization of Koiter's ζ_3 (:func:`shellobstacle.models.koiter.bending_energy`);
- ``hhj``: the moments in HHJ of degree 1 (normal-normal continuous) and ``w`` in P2, the
  saddle-point matrix ``[[A, −B], [−Bᵀ, 0]]`` with ``B`` the distributional Hessian.

One JSON line per method and ``n``: unknowns, matrix nonzeros, factorization seconds, MUMPS'
factor entries (INFOG(29)) and flops (RINFOG(3)), the centre deflection and its error.

    .venv/bin/python benchmarks/plate_bending.py --n 32,64,128
"""

from __future__ import annotations

import argparse
import json
import time

from mpi4py import MPI
from petsc4py import PETSc

import basix.ufl
import dolfinx.fem.petsc
import numpy as np
import ufl
from dolfinx import fem, mesh

CENTRE = 0.00126532  # w(1/2, 1/2) of the clamped square plate under a unit load, D = 1
SIGMA = 8.0


def hessian(u: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
    return ufl.grad(ufl.grad(u))


def c0ip(msh: mesh.Mesh) -> tuple[fem.Form, fem.Form, fem.FunctionSpace, fem.FunctionSpace]:
    """The interior-penalty forms on P2 (the deflection space is the whole space)."""
    V = fem.functionspace(msh, ("Lagrange", 2))
    w, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    n, h = ufl.FacetNormal(msh), ufl.CellDiameter(msh)
    h_avg = (h("+") + h("-")) / 2

    def m_nn(u: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        return ufl.dot(ufl.dot(hessian(u), n), n)

    def jump(u: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        return ufl.jump(ufl.grad(u), n)

    def dn(u: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        return ufl.dot(ufl.grad(u), n)

    a = (
        ufl.inner(hessian(w), hessian(v)) * ufl.dx
        + (-ufl.avg(m_nn(w)) * jump(v) - ufl.avg(m_nn(v)) * jump(w)) * ufl.dS
        + SIGMA / h_avg * jump(w) * jump(v) * ufl.dS
        + (-m_nn(w) * dn(v) - m_nn(v) * dn(w) + SIGMA / h * dn(w) * dn(v)) * ufl.ds
    )
    return fem.form(a), fem.form(v * ufl.dx), V, V


def hhj(msh: mesh.Mesh) -> tuple[fem.Form, fem.Form, fem.FunctionSpace, fem.FunctionSpace]:
    """The mixed forms on HHJ₁ × P2 (the deflection is the second sub-space)."""
    cell = msh.basix_cell()
    element = basix.ufl.mixed_element(
        [basix.ufl.element("HHJ", cell, 1), basix.ufl.element("Lagrange", cell, 2)]
    )
    W = fem.functionspace(msh, element)
    sigma, w = ufl.TrialFunctions(W)
    tau, v = ufl.TestFunctions(W)
    n = ufl.FacetNormal(msh)

    def b(t: ufl.core.expr.Expr, u: ufl.core.expr.Expr) -> ufl.core.expr.Expr:
        t_nn = ufl.dot(ufl.dot(t("+"), n("+")), n("+"))
        return (
            ufl.inner(t, hessian(u)) * ufl.dx
            - t_nn * ufl.jump(ufl.grad(u), n) * ufl.dS
            - ufl.dot(ufl.dot(t, n), n) * ufl.dot(ufl.grad(u), n) * ufl.ds
        )

    a = ufl.inner(sigma, tau) * ufl.dx - b(tau, w) - b(sigma, v)
    return fem.form(a), fem.form(-v * ufl.dx), W, W.sub(1)


def run(method: str, n: int) -> dict:
    msh = mesh.create_unit_square(MPI.COMM_WORLD, n, n)
    tdim = msh.topology.dim
    msh.topology.create_connectivity(tdim - 1, tdim)
    a, L, W, V = (c0ip if method == "c0ip" else hhj)(msh)
    collapsed = V.collapse()[0] if V is not W else V
    facets = mesh.exterior_facet_indices(msh.topology)
    if V is W:
        bc = fem.dirichletbc(0.0, fem.locate_dofs_topological(V, tdim - 1, facets), V)
    else:
        dofs = fem.locate_dofs_topological((V, collapsed), tdim - 1, facets)
        bc = fem.dirichletbc(fem.Function(collapsed), dofs, V)
    A = dolfinx.fem.petsc.assemble_matrix(a, bcs=[bc])
    A.assemble()
    rhs = dolfinx.fem.petsc.assemble_vector(L)
    dolfinx.fem.petsc.apply_lifting(rhs, [a], [[bc]])
    rhs.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    dolfinx.fem.petsc.set_bc(rhs, [bc])
    ksp = PETSc.KSP().create(msh.comm)
    ksp.setOperators(A)
    ksp.setType("preonly")
    pc = ksp.getPC()
    pc.setType("cholesky")  # not marked SPD: MUMPS' symmetric indefinite LDLᵀ for both
    pc.setFactorSolverType("mumps")
    t0 = time.perf_counter()
    ksp.setUp()
    seconds = time.perf_counter() - t0
    F = pc.getFactorMatrix()
    u = fem.Function(W)
    ksp.solve(rhs, u.x.petsc_vec)
    u.x.scatter_forward()
    w = u if V is W else u.sub(1).collapse()
    y = collapsed.tabulate_dof_coordinates()[:, :2]
    centre = float(w.x.array[np.argmin(np.linalg.norm(y - 0.5, axis=1))])
    return {
        "method": method,
        "n": n,
        "unknowns": W.dofmap.index_map.size_global * W.dofmap.index_map_bs,
        "nonzeros": int(A.getInfo()["nz_used"]),
        "factor_seconds": round(seconds, 3),
        "factor_entries": int(F.getMumpsInfog(29)),
        "factor_gflop": round(F.getMumpsRinfog(3) / 1e9, 3),
        "centre": centre,
        "centre_error": abs(centre - CENTRE) / CENTRE,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", default="32,64,128", help="squares per side, comma-separated")
    args = parser.parse_args()
    for n in (int(v) for v in args.n.split(",")):
        for method in ("c0ip", "hhj"):
            print(json.dumps(run(method, n)), flush=True)


if __name__ == "__main__":
    main()
