"""Shared pieces of the experiments: Newton's options and solves through the method registry,
transfer between nested meshes, CSV tables, rate fits."""

from __future__ import annotations

import csv
import dataclasses
import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.io.records import atomic_write
from shellobstacle.mesh.transfer import Interpolation
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.registry import METHODS
from shellobstacle.solvers.result import ConvergenceError, MethodResult

__all__ = [
    "LazyReference",
    "fit_rate",
    "on_its_mesh",
    "readable_log_ticks",
    "reference_of",
    "solve_by",
    "transfer",
    "write_csv",
]


def on_its_mesh(newton: NewtonOptions | None) -> NewtonOptions:
    """Newton's options (None: the defaults) with nested iteration off: an experiment measures
    the continuation on its own mesh (each κ, each mesh), not through coarser ones."""
    return dataclasses.replace(newton or NewtonOptions(), nested_iteration="off")


def solve_by(
    method: str, problem: Any, h: float, kappas: Sequence[float], options: Any
) -> MethodResult:
    """``METHODS[method].solve(problem, h, kappas, options)``; a failure ends the experiment.

    Raises:
        ConvergenceError: the method did not converge (its message and steps).
    """
    done = METHODS[method].solve(problem, h, kappas, options)
    if not done.converged:
        raise ConvergenceError(done.error or f"{method} did not converge", done, done.steps)
    return done


class LazyReference:
    """A reference solution computed on first use (a resumed sweep may not need it)."""

    def __init__(self, make: Callable[[], dolfinx.fem.Function]) -> None:
        self._make = make
        self._value: dolfinx.fem.Function | None = None
        self._into: Interpolation | None = None

    def get(self) -> dolfinx.fem.Function:
        """The reference (computed once, collectively)."""
        if self._value is None:
            self._value = self._make()
        return self._value

    def interpolate(self, f: dolfinx.fem.Function) -> dolfinx.fem.Function:
        """``f`` interpolated into the reference's space (each source space located once)."""
        if self._into is None:
            self._into = Interpolation(self.get().function_space)
        return self._into(f)


def reference_of(reference: Any) -> dolfinx.fem.Function | None:
    """``reference`` itself, or the value of a :class:`LazyReference`."""
    return reference.get() if isinstance(reference, LazyReference) else reference


def transfer(
    coarse: dolfinx.fem.Function, V_fine: dolfinx.fem.FunctionSpace
) -> dolfinx.fem.Function:
    """Interpolate a coarse-mesh Function into a space on a finer (nested) mesh, once
    (:class:`~shellobstacle.mesh.transfer.Interpolation` keeps the point location for repeats).

    On nested meshes a P1 coarse function is represented exactly, so differences of
    solutions on consecutive meshes measure the discretization alone (docs/model.md §7, batch 2).
    """
    return Interpolation(V_fine)(coarse)


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


def readable_log_ticks(ax: Any) -> None:
    """Label a log axis without overlaps: minor ticks unlabelled, and on an axis spanning
    less than two decades the majors at 1, 2 and 5 times the powers of ten."""
    from matplotlib.ticker import LogFormatterSciNotation, LogLocator, NullFormatter

    for axis, (lo, hi) in ((ax.xaxis, ax.get_xlim()), (ax.yaxis, ax.get_ylim())):
        if axis.get_scale() != "log" or not 0 < lo < hi:
            continue
        if np.log10(hi / lo) < 2.0:
            axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(LogFormatterSciNotation(labelOnlyBase=False))
        axis.set_minor_formatter(NullFormatter())


def finish_figure(
    fig: Any, ax: Any, path: Path, xlabel: str, ylabel: str, title: str, loglog: bool = True
) -> Path:
    """Label, grid, legend, save (rank 0, 150 dpi) and close a one-panel figure."""
    import matplotlib.pyplot as plt

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, which="both" if loglog else "major", alpha=0.3)
    if loglog:
        readable_log_ticks(ax)
    ax.legend(fontsize=8)
    fig.tight_layout()
    if MPI.COMM_WORLD.rank == 0:
        fig.savefig(path, dpi=150)
    plt.close(fig)
    return path
