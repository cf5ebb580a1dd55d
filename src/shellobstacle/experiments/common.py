"""Shared pieces of the experiments: compiled difference norms, transfer between nested meshes,
CSV tables, rate fits."""

from __future__ import annotations

import csv
import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import dolfinx
import numpy as np
import ufl
from mpi4py import MPI

from shellobstacle import compat  # noqa: F401
from shellobstacle.results import atomic_write

__all__ = [
    "DifferenceNorms",
    "LazyReference",
    "exact_solution",
    "fit_rate",
    "newton_finished",
    "reference_of",
    "transfer",
    "write_csv",
]


class LazyReference:
    """A reference solution computed on first use (a resumed sweep may not need it)."""

    def __init__(self, make: Callable[[], dolfinx.fem.Function]) -> None:
        self._make = make
        self._value: dolfinx.fem.Function | None = None

    def get(self) -> dolfinx.fem.Function:
        """The reference (computed once, collectively)."""
        if self._value is None:
            self._value = self._make()
        return self._value


def reference_of(reference: Any) -> dolfinx.fem.Function | None:
    """``reference`` itself, or the value of a :class:`LazyReference`."""
    return reference.get() if isinstance(reference, LazyReference) else reference


def newton_finished(newton_progress: Any, result: Any) -> None:
    """Tell a ``newton_progress`` callback with a ``finished`` method that a solve ended."""
    if hasattr(newton_progress, "finished"):
        newton_progress.finished(result)


class DifferenceNorms:
    """``‖u − v‖`` in V_M (H¹×H¹×L²), full H¹ and L² for Functions of one space, compiled once."""

    def __init__(self, V: dolfinx.fem.FunctionSpace, quadrature_degree: int | None = None) -> None:
        self.e = dolfinx.fem.Function(V)
        mesh = V.mesh
        md = {} if quadrature_degree is None else {"quadrature_degree": quadrature_degree}
        dx = ufl.Measure("dx", domain=mesh, metadata=md)
        e = self.e
        values = [e[i] * e[i] for i in range(3)]
        grads = [ufl.inner(ufl.grad(e[i]), ufl.grad(e[i])) for i in range(3)]
        self.forms = {
            "l2": dolfinx.fem.form(sum(values) * dx),
            "h1": dolfinx.fem.form((sum(values) + sum(grads)) * dx),
            "vm": dolfinx.fem.form((sum(values) + grads[0] + grads[1]) * dx),
        }
        self.comm = mesh.comm

    def __call__(self, u: dolfinx.fem.Function, v: dolfinx.fem.Function | None = None) -> dict:
        """The three norms of ``u − v`` (of ``u`` if ``v`` is None)."""
        self.e.x.array[:] = u.x.array if v is None else u.x.array - v.x.array
        out = {}
        for name, form in self.forms.items():
            local = dolfinx.fem.assemble_scalar(form)
            out[name] = float(np.sqrt(max(self.comm.allreduce(local, op=MPI.SUM), 0.0)))
        return out


def transfer(
    coarse: dolfinx.fem.Function, V_fine: dolfinx.fem.FunctionSpace
) -> dolfinx.fem.Function:
    """Interpolate a coarse-mesh Function into a space on a finer (nested) mesh.

    On nested meshes a P1 coarse function is represented exactly, so differences of
    solutions on consecutive meshes measure the discretization alone (MODEL.md §7, batch 2).
    """
    fine = dolfinx.fem.Function(V_fine)
    mesh = V_fine.mesh
    tdim = mesh.topology.dim
    cells = np.arange(
        mesh.topology.index_map(tdim).size_local + mesh.topology.index_map(tdim).num_ghosts,
        dtype=np.int32,
    )
    data = dolfinx.fem.create_interpolation_data(
        V_fine, coarse.function_space, cells, padding=1e-12
    )
    fine.interpolate_nonmatching(coarse, cells, data)
    fine.x.scatter_forward()
    return fine


def write_csv(path: Path, rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> None:
    """Write ``rows`` (dicts) with the given columns atomically (rank 0)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.10g}" if isinstance(v, float) else v) for k, v in row.items()})
    atomic_write(path, buf.getvalue())


def fit_rate(x: Sequence[float], y: Sequence[float]) -> float:
    """Slope of ``log y`` against ``log x`` (least squares); NaN for fewer than two points."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    keep = (x > 0) & (y > 0)
    if keep.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(x[keep]), np.log(y[keep]), 1)[0])


def exact_solution(shell: Any, mesh: dolfinx.mesh.Mesh, discretization: Any) -> tuple[Any, Any]:
    """The exact discrete VI solution ζ^h (nodal constraint, P1) on ``mesh``.

    Returns:
        ``(zeta, result)``: a Function in the P1 vector space of ``mesh`` and the
        :class:`~shellobstacle.solvers.active_set.ActiveSetResult` (KKT quality).
    """
    import dataclasses

    from shellobstacle.problem import PenalizedProblem
    from shellobstacle.solvers.active_set import ActiveSetSolver

    disc = dataclasses.replace(discretization, penalty_quadrature="vertex", degree=1)
    problem = PenalizedProblem(shell, mesh, disc)
    result = ActiveSetSolver(problem).solve()
    zeta = dolfinx.fem.Function(problem.V, name="zeta_exact")
    zeta.x.array[:] = problem.zeta.x.array
    return zeta, result


def finish_figure(
    fig: Any, ax: Any, path: Path, xlabel: str, ylabel: str, title: str, loglog: bool = True
) -> Path:
    """Label, grid, legend, save (rank 0, 150 dpi) and close a one-panel figure."""
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both" if loglog else "major", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    if MPI.COMM_WORLD.rank == 0:
        fig.savefig(path, dpi=150)
    plt.close(fig)
    return path
