"""Batch 2 (Theorem 8.1): κ = h^q fixed exponent, nested meshes h → 0; differences of solutions
on consecutive meshes ‖ζ^{h_1}_{h_1^q} − ζ^{h_2}_{h_2^q}‖ (the coarse one interpolated exactly)."""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import Config
from shellobstacle.experiments.common import (
    LazyReference,
    finish_figure,
    fit_rate,
    on_its_mesh,
    reference_of,
    solve_by,
    transfer,
    write_csv,
)
from shellobstacle.experiments.exact import exact_reference
from shellobstacle.experiments.markdown import table
from shellobstacle.experiments.picture import SolutionPicture
from shellobstacle.io.checkpoint import Checkpoint
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.mesh.refinement import refine_uniformly
from shellobstacle.mesh.transfer import Interpolation
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.post.norms import DifferenceNorms
from shellobstacle.progress import phase
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import Discretization, Shell

__all__ = [
    "MeshLevel",
    "MeshStudy",
    "keeping_levels",
    "mesh_levels",
    "mesh_study",
    "plot_mesh_study",
    "write_mesh_study",
]

log = logging.getLogger(__name__)

COLUMNS = ("h_1", "h_2", "error_VM", "error_H1")


@dataclass
class MeshLevel:
    """One mesh of the nested sequence with its compiled problem (reused over q) and Newton's
    options (its solver is the method's, kept over q inside :func:`keeping_levels`)."""

    mesh: dolfinx.mesh.Mesh
    h: float
    problem: PenalizedProblem
    options: NewtonOptions
    norms: DifferenceNorms
    #: interpolation into ``problem.V`` (the previous level's solutions, located once)
    interpolation: Interpolation
    #: resume bookkeeping: the newest saved solution on this level, and a recorded one that
    #: is not yet loaded into ``problem.zeta``
    saved: str | None = None
    restore: str | None = None


@dataclass
class MeshStudy:
    """Results of batch 2 for one exponent q."""

    q: float
    rows: list[dict[str, Any]] = field(default_factory=list)
    newton: list[int] = field(default_factory=list)
    stop_h: float | None = None
    seconds: float = 0.0
    #: ‖ζ^h_{h^q} − ζ^{h_fine}‖ against the exact solution on the finest mesh (batch 4)
    reference_rows: list[dict[str, Any]] = field(default_factory=list)

    def reference_rate(self) -> float:
        """Fitted slope of log ‖ζ^h_{h^q} − ζ_ref‖_{V_M} against log h (levels but the finest)."""
        rows = self.reference_rows[:-1]
        return fit_rate([r["h"] for r in rows], [r["error_VM"] for r in rows])

    def rate(self) -> float:
        """Fitted slope of log error_VM against log h_2."""
        return fit_rate([r["h_2"] for r in self.rows], [r["error_VM"] for r in self.rows])


def mesh_levels(
    shell: Shell,
    base: dolfinx.mesh.Mesh,
    refinements: int,
    discretization: Discretization,
    newton: NewtonOptions | None = None,
    checkpoint: Checkpoint | None = None,
) -> list[MeshLevel]:
    """The base mesh and its uniform refinements, each with a compiled problem.

    With ``checkpoint`` each level's mesh is fingerprinted (and compared on resume).
    """
    cp = checkpoint or Checkpoint(None)
    options = on_its_mesh(newton)
    levels = []
    mesh = base
    for k in range(refinements + 1):
        if k > 0:
            mesh = refine_uniformly(mesh)
        cp.check_mesh(mesh, f"level{k}_mesh")
        problem = PenalizedProblem(shell, mesh, discretization)
        levels.append(
            MeshLevel(
                mesh,
                mesh_size(mesh),
                problem,
                options,
                DifferenceNorms(problem.V, discretization.qdegree),
                Interpolation(problem.V),
            )
        )
        log.info(f"batch 2: mesh level {k}: h = {levels[-1].h:.4g}, {problem.num_dofs} dofs")
    return levels


@contextlib.contextmanager
def keeping_levels(levels: Sequence[MeshLevel]) -> Iterator[None]:
    """Inside, Newton's solver of each level is kept from one solve to the next (its contact
    zone carried over q, as a checkpoint records it)."""
    with contextlib.ExitStack() as stack:
        for level in levels:
            stack.enter_context(METHODS["newton"].keeping(level.problem))
        yield


def mesh_study(
    levels: Sequence[MeshLevel],
    q: float,
    tol: float = 2e-6,
    reference: dolfinx.fem.Function | LazyReference | None = None,
    warm: bool = True,
    checkpoint: Checkpoint | None = None,
    draw: Callable[[PenalizedProblem], Any] | None = None,
) -> MeshStudy:
    """Solve with κ = h^q on each level (continuation in κ from ζ = 0) and difference them.

    With ``reference`` (a solution in the finest level's space, e.g. the exact VI solution
    there, possibly computed on first use) every level's solution is also compared with it
    (batch 4); the tolerance stop is then not applied, so that every level is measured. With
    ``warm`` a level that already holds a solution (of a previous q) starts from it and solves
    for κ = h^q directly. With ``checkpoint`` every finished (q, level) is recorded with its
    solution (only the newest per level is kept), and recorded steps are not solved again.
    ``draw(problem)`` is called after the sweep with the last level's problem, if that level
    was solved in this run.
    """
    cp = checkpoint or Checkpoint(None)
    study = MeshStudy(q)
    t0 = time.perf_counter()
    recorded_seconds = 0.0
    previous = None
    last: MeshLevel | None = None  # the sweep's last level, if solved in this run
    with keeping_levels(levels):
        for k, level in enumerate(levels):
            key = f"q{q:.10g}_level{k}"
            record = cp.load(key)
            tag = ""
            last = level if record is None else None
            if record is None:
                for lv in (level, previous):
                    if lv is not None and lv.restore is not None:
                        solver = METHODS["newton"].kept_solver(lv.problem, lv.options)
                        cp.restore_vector(lv.restore, lv.problem.zeta)
                        cp.restore_solver(lv.restore, solver)
                        lv.restore = None
                with phase(f"batch 2 [q = {q:g}]: level {k + 1}/{len(levels)}, h = {level.h:.4g}"):
                    record = _solve_level(levels, k, q, previous, reference, warm)
                cp.save_vector(key, level.problem.zeta)
                cp.save_solver(key, METHODS["newton"].kept_solver(level.problem, level.options))
                cp.save(key, record)
                cp.drop_vector(level.saved)
                level.saved = key
            else:
                level.saved = level.restore = key
                recorded_seconds += record["seconds"]
                tag = " (recorded)"
            study.newton.append(record["newton"])
            if record["reference_row"] is not None:
                study.reference_rows.append(record["reference_row"])
            row = record["row"]
            if row is not None:
                study.rows.append(row)
                log.info(
                    f"batch 2 [q = {q:g}]: h {previous.h:.4g}→{level.h:.4g}: "
                    f"‖Δζ‖_VM = {row['error_VM']:.3e}{tag}"
                )
                if row["error_VM"] < tol and study.stop_h is None:
                    study.stop_h = level.h
                    if reference is None:
                        break
            else:
                log.info(f"batch 2 [q = {q:g}]: h = {level.h:.4g} solved{tag}")
            previous = levels[k]
    if draw is not None and last is not None:
        draw(last.problem)
    study.seconds = time.perf_counter() - t0 + recorded_seconds
    return study


def _solve_level(
    levels: Sequence[MeshLevel],
    k: int,
    q: float,
    previous: MeshLevel | None,
    reference: Any,
    warm: bool,
) -> dict[str, Any]:
    """Solve level ``k`` for κ = h^q by ``METHODS["newton"]``; the step's record (Newton
    steps, rows, seconds)."""
    t0 = time.perf_counter()
    level = levels[k]
    ladder = PenaltySpec(exponent=q).ladder(level.h)
    solved_before = warm and bool(np.any(level.problem.zeta.x.array))
    if not warm:
        level.problem.zeta.x.array[:] = 0.0
    kappas = ladder[-1:] if solved_before else ladder
    steps = solve_by("newton", level.problem, level.h, kappas, level.options).steps
    reference_row = None
    ref = reference_of(reference)
    if ref is not None:
        zeta = level.problem.zeta
        if k == len(levels) - 1:
            mine = zeta
        elif isinstance(reference, LazyReference):
            mine = reference.interpolate(zeta)
        else:
            mine = transfer(zeta, ref.function_space)
        e = levels[-1].norms(mine, ref)
        reference_row = {"q": q, "h": level.h, "error_VM": e["vm"], "error_H1": e["h1"]}
    row = None
    if previous is not None:
        coarse = level.interpolation(previous.problem.zeta)
        d = level.norms(coarse, level.problem.zeta)
        row = {"h_1": previous.h, "h_2": level.h, "error_VM": d["vm"], "error_H1": d["h1"]}
    return {
        "q": q,
        "level": k,
        "newton": sum(s.newton.iterations for s in steps),
        "reference_row": reference_row,
        "row": row,
        "seconds": time.perf_counter() - t0,
    }


def write_mesh_study(study: MeshStudy, folder: Path) -> Path:
    """``batch2_q<q>.csv`` (columns h_1, h_2, error_VM, error_H1)."""
    path = folder / f"batch2_q{study.q:g}.csv"
    write_csv(path, study.rows, COLUMNS)
    return path


def plot_mesh_study(study: MeshStudy, path: Path, tol: float = 2e-6) -> Path:
    """Differences on consecutive meshes against h_2, with the slope-1 reference of Theorem 8.1."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    h = np.array([r["h_2"] for r in study.rows])
    e = np.array([r["error_VM"] for r in study.rows])
    ax.loglog(h, e, "o-", label="‖ζ(h_1) − ζ(h_2)‖ in V_M")
    ax.loglog(h, [r["error_H1"] for r in study.rows], "s--", label="full H¹ norm")
    if h.size:
        ax.loglog(h, e[0] * h / h[0], "k:", lw=1, label="slope 1")
    ax.axhline(tol, color="grey", lw=0.8, ls=":")
    return finish_figure(
        fig,
        ax,
        path,
        "h_2 (finer mesh)",
        "difference",
        f"Batch 2: κ = h^{study.q:g}, nested meshes (fitted rate {study.rate():.2f})",
    )


def run_mesh(
    cfg: Config,
    folder: Path,
    base: DomainSpec,
    refinements: int,
    q_values: Sequence[float],
    tol: float = 2e-6,
    batch4: list[dict[str, Any]] | None = None,
    checkpoint: Checkpoint | None = None,
) -> str:
    """Batch 2 on nested meshes for each q; returns the report section.

    With a ``batch4`` list, every level's solution is also compared with the exact nodal VI
    solution on the finest mesh, and the rows are appended to it. With ``checkpoint`` every
    (q, level) is recorded and recorded ones are not solved again.
    """
    cp = (checkpoint or Checkpoint(None)).scope("batch2")
    text = [
        "## Batch 2: h → 0 with κ = h^q (Theorem 8.1)",
        "",
        f"Nested meshes (uniform refinement of a disk mesh, {refinements} times); the coarse "
        "solution is interpolated exactly into the fine space. Theorem 8.1 bounds the error by "
        "C h (1 + 1/√κ) = O(h^{1 − q/2}).",
        "",
    ]
    coarsest = make_mesh(base)
    levels = mesh_levels(cfg.shell, coarsest, refinements, cfg.discretization, cfg.solver, cp)
    reference = None
    if batch4 is not None:
        where = f"the finest mesh (h = {levels[-1].h:.4g})"
        make = exact_reference(cfg, levels[-1].mesh, cfg.discretization, where)
        reference = LazyReference(make)
    summary = []
    picture = SolutionPicture(cfg, folder / "batch2_shell_3d.png")
    draw = picture.drawer(f"Batch 2, κ = h^{q_values[-1]:g}")
    with keeping_levels(levels):  # each level's solver carried over q
        for q in q_values:
            s = mesh_study(
                levels,
                q,
                tol,
                reference,
                checkpoint=cp,
                draw=draw if q == q_values[-1] else None,
            )
            if batch4 is not None:
                batch4.extend(s.reference_rows)
            write_mesh_study(s, folder)
            png = folder / f"batch2_q{q:g}.png"
            if MPI.COMM_WORLD.rank == 0:
                plot_mesh_study(s, png, tol)
            summary.append(
                {
                    "q": q,
                    "fitted rate": s.rate(),
                    "theory 1 − q/2": 1 - q / 2,
                    "stops at h": s.stop_h if s.stop_h else "not reached",
                    "Newton (per mesh)": "/".join(map(str, s.newton)),
                    "seconds": s.seconds,
                }
            )
            text += [
                f"### q = {q:g}",
                "",
                table(s.rows, ("h_1", "h_2", "error_VM", "error_H1")),
                "",
                f"![batch 2, q = {q:g}]({png.name})",
                "",
            ]
    for level in levels:  # the sweep is complete: no later step starts from these
        cp.drop_vector(level.saved)
    text += picture.markdown(f"the shell in 3D on the last mesh solved for q = {q_values[-1]:g}")
    text += ["### Summary", "", table(summary, list(summary[0])), ""]
    return "\n".join(text)
