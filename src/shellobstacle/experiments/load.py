"""Batch 3 (physics): a load parameter ℓ sweeps the load; the contact area must grow with ℓ.

The area is the nodal figure (``contact_area_nodal``: at the P1 vertices or the P2 nodes,
docs/model.md §7), the paper's measure, whatever points the penalty acts at.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import Config
from shellobstacle.experiments.common import finish_figure, on_its_mesh, solve_by, write_csv
from shellobstacle.experiments.markdown import table
from shellobstacle.experiments.picture import SolutionPicture
from shellobstacle.io.checkpoint import Checkpoint
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.spec import PenaltySpec, at_exponent
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.plotting import plot_cross_section
from shellobstacle.post.sections import CrossSection
from shellobstacle.post.validity import assess
from shellobstacle.progress import phase
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.registry import METHODS
from shellobstacle.spec import Discretization, Load, Shell

__all__ = [
    "PAPER_BATCH3_LOAD",
    "LoadStudy",
    "is_paper_load",
    "load_study",
    "plot_contact_area",
    "write_load_study",
]

log = logging.getLogger(__name__)

#: The paper's g_ℓ (docs/model.md §7, batch 3) with ℓ as the load parameter ``ell``.
PAPER_BATCH3_LOAD = (
    "Piecewise((-(2*epsilon/25)*(-5.0*y1**2 - 5.0*y2**2 + (1 + 0.05*ell)*0.295), r < 0.060),"
    " (0, True))"
)
COLUMNS = (
    "ell",
    "contact_area_nodal",
    "contact_area_nodal_projected",
    "max_violation_nodal",
    "zeta3_min",
)


@dataclass
class LoadStudy:
    """Contact quantities (the nodal figures) and cross-sections per value of the load
    parameter."""

    parameter: str
    h: float
    kappa: float
    dofs: int
    rows: list[dict[str, Any]] = field(default_factory=list)
    sections: list[tuple[str, CrossSection]] = field(default_factory=list)
    seconds: float = 0.0

    def area_increases(self) -> bool:
        """Whether the nodal contact area is nondecreasing in the parameter and grows overall."""
        a = np.array([r["contact_area_nodal"] for r in self.rows])
        return bool(np.all(np.diff(a) >= 0) and a[-1] > a[0])


def load_study(
    shell: Shell,
    mesh: dolfinx.mesh.Mesh,
    discretization: Discretization,
    penalty: PenaltySpec,
    values: Sequence[float],
    parameter: str = "ell",
    newton: NewtonOptions | None = None,
    checkpoint: Checkpoint | None = None,
    last: Callable[[Postprocessor], Any] | None = None,
) -> LoadStudy:
    """Solve for each value of the load parameter (one compiled problem, warm starts) by
    ``METHODS["newton"]``, its solver kept from value to value.

    With ``checkpoint`` every finished value is recorded (its row, its cross-section and its
    solution, from which the next value starts); recorded values are not solved again.
    ``last(post)`` is called once the last value is solved (not when it is recorded), with
    its solution in ``post.problem.zeta`` (e.g. to draw it).
    """
    cp = checkpoint or Checkpoint(None)
    if parameter not in shell.load.parameters:
        raise ValueError(
            f"the load has no parameter {parameter!r}: add it to [load] parameters "
            f"(it has {sorted(shell.load.parameters)})"
        )
    h = mesh_size(mesh)
    cp.check_mesh(mesh)
    problem = PenalizedProblem(shell, mesh, discretization)
    method, options = METHODS["newton"], on_its_mesh(newton)
    post = Postprocessor(problem)
    ladder = penalty.ladder(h)
    study = LoadStudy(parameter, h, ladder[-1], problem.num_dofs)
    t0 = time.perf_counter()
    recorded_seconds = 0.0
    restore: str | None = None  # the recorded solution not yet loaded into problem.zeta
    saved: str | None = None  # the newest saved solution
    with method.keeping(problem):
        for k, value in enumerate(values):
            key = f"{parameter}{value:.10g}"
            record = cp.load(key)
            tag = ""
            if record is None:
                if restore is not None:
                    solver = method.kept_solver(problem, options)
                    cp.restore_vector(restore, problem.zeta)
                    cp.restore_solver(restore, solver)
                    restore = None
                ts = time.perf_counter()
                problem.set_parameter(parameter, value)
                with phase(f"batch 3: {parameter} = {value:g} ({k + 1}/{len(values)})"):
                    kappas = ladder if k == 0 else ladder[-1:]
                    steps = solve_by("newton", problem, h, kappas, options).steps
                c = post.contact()
                validity = assess(post, float(problem.kappa.value))
                row = {
                    parameter: value,
                    "ell": value,
                    "contact_area_nodal": c["contact_area_nodal"],
                    "contact_area_nodal_projected": c["contact_area_nodal_projected"],
                    "max_violation_nodal": c["max_violation_nodal"],
                    "zeta3_min": post.zeta3_range()[0],
                    "newton": sum(s.newton.iterations for s in steps),
                    "violations": validity.violations,
                }
                for line in validity.warnings():
                    log.warning(f"{parameter} = {value:g}: {line}")
                section = dataclasses.asdict(post.cross_section())
                record = {"row": row, "section": section, "seconds": time.perf_counter() - ts}
                cp.save_vector(key, problem.zeta)
                cp.save_solver(key, method.kept_solver(problem, options))
                cp.save(key, record)
                cp.drop_vector(saved)
                saved = key
                if last is not None and k == len(values) - 1:
                    last(post)
            else:
                restore = saved = key
                recorded_seconds += record["seconds"]
                tag = " (recorded)"
            study.rows.append(record["row"])
            section = {
                name: np.asarray(v) if isinstance(v, list) else v
                for name, v in record["section"].items()
            }
            study.sections.append((f"{parameter} = {value:g}", CrossSection(**section)))
            area = record["row"]["contact_area_nodal"]
            log.info(f"batch 3: {parameter} = {value:g}: contact area {area:.6g} (nodal){tag}")
    cp.drop_vector(saved)  # the sweep is complete
    study.seconds = time.perf_counter() - t0 + recorded_seconds
    return study


def write_load_study(study: LoadStudy, folder: Path) -> Path:
    """``batch3.csv``: ell, contact_area_nodal, contact_area_nodal_projected,
    max_violation_nodal, zeta3_min."""
    path = folder / "batch3.csv"
    write_csv(path, study.rows, COLUMNS)
    return path


def plot_contact_area(study: LoadStudy, path: Path, paper_load: bool = False) -> Path:
    """The nodal contact area (surface and projected) against the load parameter; with
    ``paper_load`` also the area of the paper's loaded disk ``|y| < 0.06``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ell = [r["ell"] for r in study.rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(ell, [r["contact_area_nodal"] for r in study.rows], "o-", label="area with √a dy")
    area = [r["contact_area_nodal_projected"] for r in study.rows]
    ax.plot(ell, area, "s--", label="projected (dy)")
    if paper_load:
        ax.axhline(np.pi * 0.06**2, color="grey", ls=":", label="loaded disk |y| < 0.06 (π·0.06²)")
    return finish_figure(
        fig,
        ax,
        path,
        study.parameter,
        "contact area at the nodes",
        f"Batch 3: contact area vs {study.parameter} (h = {study.h:.4g}, κ = {study.kappa:.2e})",
        loglog=False,
    )


def run_load(
    cfg: Config,
    folder: Path,
    domain: DomainSpec,
    values: Sequence[float],
    exponent: float,
    parameter: str = "ell",
    checkpoint: Checkpoint | None = None,
) -> str:
    """Batch 3 (load sweep); returns the report section.

    With ``checkpoint`` every value is recorded and recorded values are not solved again.
    The largest load's solution is drawn in 3D (``batch3_shell_3d.png``, when
    ``output.pictures``; a resumed run keeps the drawing of the run that solved it).
    """
    picture = SolutionPicture(cfg, folder / "batch3_shell_3d.png")
    paper_load = is_paper_load(cfg.shell.load)
    name = "ℓ" if paper_load and parameter == "ell" else parameter

    def draw(post: Postprocessor) -> None:
        picture.draw(post, f"Batch 3: the deformed shell over the plane at {name} = {values[-1]:g}")

    s = load_study(
        cfg.shell,
        make_mesh(domain),
        cfg.discretization,
        at_exponent(cfg.penalty, exponent),
        values,
        parameter,
        cfg.solver,
        (checkpoint or Checkpoint(None)).scope("batch3"),
        draw,
    )
    write_load_study(s, folder)
    png_area = folder / "batch3_contact_area.png"
    png_sections = folder / "batch3_cross_sections.png"
    plot_cross_section(
        s.sections,
        cfg.shell.obstacle.q,
        png_sections,
        title=f"Batch 3: cross-sections y2 = 0 for {parameter} = "
        + ", ".join(f"{v:g}" for v in values),
    )
    if MPI.COMM_WORLD.rank == 0:
        plot_contact_area(s, png_area, paper_load)
    verdict = "grows" if s.area_increases() else "does NOT grow monotonically"
    invalid = [
        f"{parameter} = {r[parameter]:g} ({', '.join(r['violations'])})"
        for r in s.rows
        if r.get("violations")
    ]
    validity = (
        "**Outside the model's validity** (`shellobstacle.post.validity`, the user guide's "
        f'"Validity of a solution"): {"; ".join(invalid)}.'
        if invalid
        else "Every solution is inside the model's validity (penetration, displacement, "
        "orientation within their thresholds)."
    )
    shell_3d = picture.markdown(f"the shell in 3D at {name} = {values[-1]:g}")
    return "\n".join(
        [
            "## Batch 3: the contact area as the load grows",
            "",
            f"{_load_text(cfg.shell.load, paper_load)}; h = {s.h:.4g}{_refined_text(domain)}, "
            f"κ = h^{exponent:g} = {s.kappa:.3e}, {s.dofs} dofs. "
            f"The contact area {verdict} with {name}. Areas are measured on the nodes "
            f"(`contact_area_nodal`: the lumped masses of the nodes with g ≤ 0). {validity}",
            "",
            table(
                s.rows,
                (
                    "ell",
                    "contact_area_nodal",
                    "contact_area_nodal_projected",
                    "max_violation_nodal",
                    "zeta3_min",
                    "newton",
                ),
            ),
            "",
            f"![cross-sections]({png_sections.name})",
            "",
            *shell_3d,
            f"![contact area]({png_area.name})",
            "",
        ]
    )


def is_paper_load(load: Load) -> bool:
    """Whether ``load`` is the paper's g_ℓ of batch 3 (:data:`PAPER_BATCH3_LOAD`)."""
    return tuple(load.p) == ("0", "0", PAPER_BATCH3_LOAD)


def _load_text(load: Load, paper_load: bool) -> str:
    """The load as the report states it: the paper's formula for its g_ℓ, else the config's."""
    if paper_load:
        return "g_ℓ = −(2ε/25)(−5y1² − 5y2² + (1 + 0.05ℓ)·0.295) on |y| < 0.06"
    return "p = (" + ", ".join(f"`{c}`" for c in load.p) + ")"


def _refined_text(domain: DomainSpec) -> str:
    """How the mesh is refined near the centre, if it is."""
    if domain.central_h is None:
        return ""
    return (
        f" (refined near the centre: {domain.central_h:g} within {domain.central_radius:g} "
        f"of {domain.center})"
    )


def batch3_config(cfg: Config) -> Config:
    """The paper's configuration with the ℓ-dependent load of batch 3."""
    shell = dataclasses.replace(cfg.shell, load=Load(("0", "0", PAPER_BATCH3_LOAD), {"ell": 0.0}))
    return dataclasses.replace(cfg, shell=shell)
