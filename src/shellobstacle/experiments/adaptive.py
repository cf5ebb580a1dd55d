"""Adaptive against uniform refinement: the ``V_M`` error against the number of dofs.

Two sequences start from the same mesh: uniform (red) refinements, each solved like
``solve`` does (``κ = h^q`` reached by continuation from ζ = 0, or the exact VI), and the
adaptive loop of the config (:mod:`shellobstacle.adapt.loop`: its method, ``[adapt]``
marking and κ). The reference ``ζ_ref`` continues the adaptive loop with the exact discrete
VI (κ = 0: no penalty error) up to ``reference_dofs``: it is the suggestion "a finer
adapted mesh, or the exact VI on it", and its mesh refines every adapted one, so the
adaptive levels' errors ``‖ζ_h − ζ_ref‖_{V_M}`` are exact integrals of interpolated P1
functions. The uniform meshes are not nested with it: their errors are integrated on the
reference mesh with the uniform solution sampled at its Gauss points
(:mod:`shellobstacle.post.nonmatching`). Times are wall times as the solves run: a uniform
level's refinement, compilation and continuation; an adaptive level's, the whole loop up to
its solution (every coarser level, estimate and refinement included).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.adapt.loop import AdaptiveResult, AdaptLevel, adaptive_solve, carry_over
from shellobstacle.adapt.options import MAX_LEVELS, AdaptOptions
from shellobstacle.api import make_mesh
from shellobstacle.config.loader import Config
from shellobstacle.experiments.common import fit_rate, write_csv
from shellobstacle.experiments.markdown import table
from shellobstacle.experiments.picture import SolutionPicture
from shellobstacle.io.checkpoint import Checkpoint
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.post.nonmatching import SampledNorms
from shellobstacle.post.norms import DifferenceNorms
from shellobstacle.solvers.registry import METHODS
from shellobstacle.solvers.result import ConvergenceError

__all__ = ["COLUMNS", "AdaptiveStudy", "AdaptiveStudyOptions", "adaptive_study", "run_adaptive"]

log = logging.getLogger(__name__)

COLUMNS = (
    "sequence", "level", "dofs", "h_min", "h_max", "kappa_min", "kappa_max", "eta",
    "error_VM", "efficiency", "eta_tangential", "eta_normal", "eta_jump", "eta_contact",
    "iterations", "seconds",
)  # fmt: skip
UNIFORM, ADAPTIVE = "uniform", "adaptive"


@dataclass(frozen=True)
class AdaptiveStudyOptions:
    """Sizes of the study.

    Attributes:
        refinements: uniform refinements of the first mesh.
        reference_dofs: the exact VI's adaptive loop stops at the first mesh with at least
            this many dofs; its solution there is the reference.
        dofs: the config's adaptive loop stops at the first mesh with at least this many dofs
            (None: ``adapt.target_dofs``, else ``reference_dofs / 8``).
    """

    refinements: int = 3
    reference_dofs: int = 200_000
    dofs: int | None = None


@dataclass
class AdaptiveStudy:
    """Rows of the two sequences, the reference's size, and the adaptive loop's result."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    reference: dict[str, Any] = field(default_factory=dict)
    final: AdaptiveResult | None = None
    #: the solver failure that ended the adaptive loop early, if one did
    failure: str | None = None
    #: why the reference is not at ``reference_dofs``, if it is not
    reference_note: str | None = None

    def sequence(self, name: str) -> list[dict[str, Any]]:
        """The rows of one sequence."""
        return [r for r in self.rows if r["sequence"] == name]

    def rate(self, name: str) -> float:
        """Fitted slope of log error_VM against log dofs over the rows of ``name`` whose dofs
        are at least twice the first mesh's and at most 1/8 of the reference's (where the
        reference's own error is small against theirs)."""
        rows = self.sequence(name)
        if not rows:
            return float("nan")
        low, high = 2 * rows[0]["dofs"], self.reference["dofs"] / 8
        used = [r for r in rows if low <= r["dofs"] <= high] if name != UNIFORM else rows
        return fit_rate([r["dofs"] for r in used], [r["error_VM"] for r in used])

    def reached(self, name: str) -> dict[str, Any] | None:
        """The first row of ``name`` whose error is at most the finest uniform mesh's."""
        uniform = self.sequence(UNIFORM)
        if not uniform:
            return None
        target = uniform[-1]["error_VM"]
        return next((r for r in self.sequence(name) if r["error_VM"] <= target), None)


def _row(name: str, level: AdaptLevel, error: float, seconds: float) -> dict[str, Any]:
    data = {"sequence": name, **level.as_dict(), "error_VM": error, "seconds": seconds}
    return data | {"efficiency": level.eta / error if error > 0 else float("nan")}


def _cumulative(levels: list[AdaptLevel]) -> list[float]:
    """Wall time of the loop up to each level's solution (coarser levels in full)."""
    out, total = [], 0.0
    for lv in levels:
        s = lv.seconds
        out.append(total + s.get("setup", 0.0) + s.get("solve", 0.0))
        total += sum(s.values())
    return out


def _adaptive(
    cfg: Config,
    mesh: dolfinx.mesh.Mesh,
    adapt: AdaptOptions,
    method: str,
    carried: list[dolfinx.fem.Function],
    keep: bool,
    start: dolfinx.fem.Function | None = None,
) -> tuple[AdaptiveResult, dolfinx.fem.Function]:
    """The adaptive loop by ``method``: its result and last converged solution. Every
    function in ``carried`` is carried onto each refined mesh; with ``keep`` every level's
    solution joins them. A solver failure after the first level ends the loop (the result
    says so); on the first level it raises."""
    last: list[Any] = []

    def on_level(level: AdaptLevel, problem: Any) -> None:
        zeta = dolfinx.fem.Function(problem.V)
        zeta.x.array[:] = problem.zeta.x.array
        last[:] = [zeta, problem]
        if keep:
            carried.append(zeta)

    penalty = cfg.penalty if METHODS[method].penalized else None
    result = adaptive_solve(
        cfg.shell, mesh, cfg.discretization, penalty, adapt, cfg.solver, method,
        cfg.method_options if method == cfg.method else None, on_level, start, carried,
    )  # fmt: skip
    if not result.converged and not last:
        raise ConvergenceError(f"adaptive level 0: {result.error}")
    result.problem = last[1]  # the last level solved
    return result, last[0]


def adaptive_study(
    cfg: Config,
    domain: DomainSpec,
    options: AdaptiveStudyOptions,
    checkpoint: Checkpoint | None = None,
) -> AdaptiveStudy:
    """Run the sequences on ``domain``'s mesh and measure their errors.

    The adaptive loop of the config runs to ``options.dofs``; the exact VI's adaptive loop
    continues from its last mesh and solution to ``options.reference_dofs``. Every adapted
    mesh is refined by the last one: each level's solution is carried (interpolated exactly,
    with the point location of the warm starts) onto the reference mesh. With
    ``checkpoint`` each uniform level's row is recorded and not solved again on resume; the
    adaptive loops are deterministic and run again.
    """
    cp = checkpoint or Checkpoint(None)
    adapt = cfg.adapt or AdaptOptions()
    study = AdaptiveStudy()
    base = make_mesh(domain, ghosted=True)
    dofs = options.dofs or adapt.target_dofs or options.reference_dofs // 8
    run = dataclasses.replace(adapt, max_levels=MAX_LEVELS, target_dofs=dofs, target_error=None)
    log.info(f"adaptive study: {cfg.method}, κ '{adapt.kappa}', adapted up to {dofs} dofs")
    solutions: list[dolfinx.fem.Function] = []
    result, last = _adaptive(cfg, base, run, cfg.method, solutions, True)
    study.final = result
    if not result.converged:
        study.failure = f"level {len(result.levels)}: {result.error}"
        log.info(f"adaptive study: the adaptive loop stopped at {study.failure}")

    log.info(
        f"adaptive study: the reference, the exact VI adapted up to {options.reference_dofs} dofs"
    )
    exact_options = dataclasses.replace(run, target_dofs=options.reference_dofs)
    exact, reference = _adaptive(
        cfg, result.problem.mesh, exact_options, "active-set", solutions, False, last
    )
    if not exact.converged:  # the last level solved is the reference
        study.reference_note = (
            f"the exact solver failed on the next level ({exact.error}); the reference is "
            "its last solved level"
        )
        log.info(f"adaptive study: {study.reference_note}")
        solutions[:] = carry_over(solutions, reference.function_space)
    ref = exact.levels[-1]
    study.reference = {"dofs": ref.dofs, "eta": ref.eta, "h_min": ref.h_min}
    nested = DifferenceNorms(reference.function_space, cfg.discretization.qdegree)
    times = _cumulative(result.levels)
    for level, zeta, t in zip(result.levels, solutions, times, strict=True):
        study.rows.append(_row(ADAPTIVE, level, nested(zeta, reference)["vm"], t))
    solutions.clear()

    from shellobstacle.experiments.adaptive_uniform import uniform_sequence

    norms = SampledNorms(reference)
    study.rows += uniform_sequence(cfg, base, options.refinements, norms, cp)
    return study


def write_adaptive_study(study: AdaptiveStudy, folder: Path) -> Path:
    """``adaptive.csv`` (the columns of :data:`COLUMNS`)."""
    path = folder / "adaptive.csv"
    write_csv(path, study.rows, COLUMNS)
    return path


def plot_adaptive_study(study: AdaptiveStudy, path: Path) -> Path:
    """``V_M`` error (solid) and estimate ``η`` (dotted) against dofs, log–log, with the
    fitted slopes; the finest uniform mesh's error as a horizontal line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from shellobstacle.experiments.common import finish_figure

    fig, ax = plt.subplots(figsize=(6.8, 5.0))
    styles = {UNIFORM: ("o-", "tab:blue"), ADAPTIVE: ("s-", "tab:orange")}
    for name, (style, color) in styles.items():
        rows = study.sequence(name)
        if not rows:
            continue
        n = [r["dofs"] for r in rows]
        label = f"{name} (slope {study.rate(name):.2f})"
        ax.loglog(n, [r["error_VM"] for r in rows], style, color=color, ms=4, label=label)
        ax.loglog(n, [r["eta"] for r in rows], ":", color=color, lw=1, label=f"{name}: η")
    uniform = study.sequence(UNIFORM)
    if uniform:
        ax.axhline(uniform[-1]["error_VM"], color="0.5", lw=0.8, ls="--")
    ax.axvline(study.reference["dofs"], color="0.5", lw=0.8, ls=":", label="reference")
    return finish_figure(
        fig, ax, path, "dofs N", "‖ζ_h − ζ_ref‖ in V_M",
        "Adaptive against uniform refinement (error ∝ N^slope)",
    )  # fmt: skip


def run_adaptive(
    cfg: Config,
    folder: Path,
    domain: DomainSpec,
    options: AdaptiveStudyOptions,
    checkpoint: Checkpoint | None = None,
) -> str:
    """The study with its CSV, figures and report section."""
    from shellobstacle.adapt.picture import plot_adapted_mesh
    from shellobstacle.post.contact import Postprocessor

    cp = (checkpoint or Checkpoint(None)).scope("adaptive")
    study = adaptive_study(cfg, domain, options, cp)
    write_adaptive_study(study, folder)
    plot_adaptive_study(study, folder / "adaptive.png")
    final = study.final
    assert final is not None
    problem = final.problem
    post = Postprocessor(problem)
    contact = post.indicator()
    cx, cy, w = _zoom(problem.mesh, contact)
    last = final.levels[-1]
    zooms = [(cx, cy, w)] + ([(cx, cy, 50 * last.h_min)] if 50 * last.h_min < w / 4 else [])
    plot_adapted_mesh(
        problem.mesh, contact, folder / "adaptive_mesh.png",
        f"the last adapted mesh: {last.dofs} dofs, h_min = {last.h_min:.2g}", zooms,
    )  # fmt: skip
    picture = SolutionPicture(cfg, folder / "adaptive_shell_3d.png")
    picture.draw(post, f"The solution on the last adapted mesh ({last.dofs} dofs)")
    return _section(cfg, study, options) + "\n".join(
        ["", *picture.markdown("the solution on the last adapted mesh in 3D")]
    )


def _zoom(mesh: dolfinx.mesh.Mesh, contact: dolfinx.fem.Function) -> tuple[float, float, float]:
    """A close-up around the rightmost point of the contact set's boundary (else the
    domain's centre), 1/40 of the domain's width wide on each side."""
    from shellobstacle.adapt.marking import free_boundary_cells

    x = mesh.geometry.x
    width = mesh.comm.allreduce(float(np.ptp(x[:, 0])) if x.size else 0.0, op=MPI.MAX)
    cells = free_boundary_cells(mesh, contact.x.array > 0.5)
    mid = dolfinx.mesh.compute_midpoints(mesh, mesh.topology.dim, cells)
    best = (float(mid[:, 0].max()), float(mid[np.argmax(mid[:, 0]), 1])) if cells.size else None
    found = [b for b in mesh.comm.allgather(best) if b is not None]
    cx, cy = max(found) if found else (0.0, 0.0)
    return cx, cy, width / 40.0


def _section(cfg: Config, study: AdaptiveStudy, options: AdaptiveStudyOptions) -> str:
    """The report section: the tables, slopes, the cost of the finest uniform error."""
    adapt = cfg.adapt or AdaptOptions()
    ref = study.reference
    text = [
        "## Adaptive refinement (beyond the paper)",
        "",
        f"From the same first mesh: {options.refinements} uniform refinements and the adaptive "
        f"loop ({cfg.method}; Dörfler θ = {adapt.fraction:g}, κ '{adapt.kappa}', free-boundary "
        f"marking {'on' if adapt.free_boundary else 'off'}). The reference continues the "
        f"adaptive loop with the exact VI up to {ref['dofs']} dofs (η = {ref['eta']:.3g}, "
        f"h_min = {ref['h_min']:.3g}); errors are ‖ζ_h − ζ_ref‖_{{V_M}} (uniform meshes: "
        "sampled at the reference's Gauss points), slopes are fitted to error ∝ N^slope "
        "(adaptive: over the levels with 2 N_0 ≤ N ≤ N_ref/8), efficiency is η / error. "
        "Seconds: a uniform level's own refinement and solve; an adaptive level's, the whole "
        "loop up to it.",
        "",
    ]
    for name in (UNIFORM, ADAPTIVE):
        rows = study.sequence(name)
        if rows:
            cols = ["level", "dofs", "h_min", "eta", "error_VM", "efficiency", "iterations"]
            cols.append("seconds")
            text += [f"### {name}: slope {study.rate(name):.3f}", "", table(rows, cols), ""]
    if study.reference_note:
        text += [
            f"The reference has fewer than {options.reference_dofs} dofs: {study.reference_note}.",
            "",
        ]
    if study.failure:
        text += [
            f"The adaptive loop stopped early, the solver failing on {study.failure}; the "
            "reference continues from its last solved level.",
            "",
        ]
    uniform = study.sequence(UNIFORM)
    if uniform:
        u = uniform[-1]
        text.append(
            f"The finest uniform mesh ({u['dofs']} dofs) has the error {u['error_VM']:.3e} "
            f"in {u['seconds']:.1f} s."
        )
        r = study.reached(ADAPTIVE)
        text.append(
            f"Adaptive level {r['level']} ({r['dofs']} dofs, {r['dofs'] / u['dofs']:.3f} of the "
            f"uniform dofs) has the error {r['error_VM']:.3e} after {r['seconds']:.1f} s."
            if r
            else "The adaptive levels do not reach it."
        )
    text += ["", "![error against dofs](adaptive.png)", "", "![mesh](adaptive_mesh.png)", ""]
    return "\n".join(text)
