"""Write a solve's result folder: summary.json, ParaView files, the cross-section figure and
the 3D picture."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mpi4py import MPI

from shellobstacle.checks.assumptions import format_checks
from shellobstacle.io.records import versions, write_json
from shellobstacle.progress import phase

if TYPE_CHECKING:
    from shellobstacle.post.contact import Postprocessor
    from shellobstacle.solvers.result import SolveResult

__all__ = ["write_solution"]

log = logging.getLogger(__name__)


def write_solution(
    result: SolveResult,
    cfg: Any,
    folder: Path,
    warnings_seen: list[str] | None = None,
) -> dict[str, Any]:
    """Write ``summary.json`` (always, also after a failure), ParaView files and figures;
    the validity measures (:mod:`shellobstacle.post.validity`) are logged as warnings.

    ``summary.json`` is written first, with ``outputs_complete`` false, and again once the
    other files are written: a run stopped in between (Ctrl-C: also ``interrupted``) leaves
    the solution's record, listing in ``files`` the files it wrote.

    Returns:
        The summary dictionary.
    """
    from shellobstacle.post.resolution import unresolved_obstacle

    problem = result.problem
    t = time.perf_counter()
    post = result.post
    quantities = post.summary()
    validity = result.validity
    unresolved = unresolved_obstacle(post.points, post.tolerance())
    solution_warnings = [*validity.warnings(), *([unresolved] if unresolved else [])]
    for line in solution_warnings:
        log.warning(line)
    timings = dict(result.timings)
    timings["postprocess"] = time.perf_counter() - t
    last = result.steps[-1] if result.steps else None
    summary: dict[str, Any] = {
        "converged": result.converged,
        "error": result.error,
        "method": result.method,
        "model": problem.model,
        "iterations": result.iterations,
        "iterations_last_kappa": last.iterations if last else 0,
        "dofs": problem.num_dofs,
        "h": result.h,
        "kappa": result.solved_kappa,
        "kappa_target": result.kappa,
        **quantities,
        "residual_history": last.residual_norms if last else [],
        "continuation": [s.as_dict() for s in result.steps],
        **{k: v for k, v in result.extra.items() if isinstance(v, int | float | str | dict)},
        "checks": [
            {
                "name": c.name,
                "quantity": c.quantity,
                "value": c.value,
                "where": c.where,
                "requirement": c.requirement,
                "passed": c.passed,
            }
            for c in result.checks
        ],
        "validity": validity.as_dict(),
        "warnings": [*(warnings_seen or []), *solution_warnings],
        "surface": cfg.shell.surface.description,
        "timings": timings,
        "versions": versions(),
    }
    # the solution's record first: a run stopped while it writes the files below (Ctrl-C, a
    # kill) leaves a summary.json that says so and lists the files written
    files: list[str] = []
    summary["files"] = files
    summary["outputs_complete"] = False
    write_json(folder / "summary.json", summary)
    if MPI.COMM_WORLD.rank == 0:
        (folder / "checks.txt").write_text(format_checks(result.checks) + "\n")
    t = time.perf_counter()
    try:
        _write_outputs(result, cfg, post, summary, folder)
    except KeyboardInterrupt:
        summary["interrupted"] = "while writing the outputs (those written are in 'files')"
        write_json(folder / "summary.json", summary)
        raise
    timings["output"] = time.perf_counter() - t
    summary["outputs_complete"] = True
    write_json(folder / "summary.json", summary)
    log.info(f"wrote summary.json and {len(files)} other file(s)")
    return summary


def _write_outputs(
    result: SolveResult,
    cfg: Any,
    post: Postprocessor,
    summary: dict[str, Any],
    folder: Path,
) -> None:
    """The ParaView files, the cross-section and the 3D picture, each added to
    ``summary["files"]`` once written (``summary["warnings"]``: a picture not drawn)."""
    from shellobstacle.io.paraview import write_paraview
    from shellobstacle.post.contact import contact_text
    from shellobstacle.post.plotting import plot_cross_section

    problem = result.problem
    output = cfg.output
    files = summary["files"]
    if output.get("paraview", True):
        extra = []
        pressure = result.extra.get("contact_pressure")
        if pressure is not None:
            extra.append(pressure.copy())
            extra[-1].name = "contact_pressure"
        with phase("writing the ParaView files"):
            paths = write_paraview(problem, post, folder, extra)
        files += [str(p.relative_to(folder)) for p in paths]
    if output.get("figures", True):
        section = post.cross_section()
        png = folder / "cross_section.png"
        label = f"κ = {summary['kappa']:.2e}" + ("" if result.converged else " (NOT converged)")
        plot_cross_section([(label, section)], problem.q, png)
        files.append(png.name)
        if "adapt" in result.extra:
            from shellobstacle.adapt.picture import plot_adapted_mesh

            title = f"adapted mesh: {problem.num_dofs} dofs"
            plot_adapted_mesh(problem.mesh, post.indicator(), folder / "mesh.png", title)
            files.append("mesh.png")
    if output.get("figures", True) and output.get("pictures", True):
        from shellobstacle.post.pictures import describe, write_picture

        title = (
            f"Deformed middle surface θ + ζᵢ aⁱ over {describe(problem.obstacle)}:\n"
            f"κ = {summary['kappa']:.2e}, {contact_text(summary, '.4g')}"
            + ("" if result.converged else " (NOT converged)")
        )
        with phase("drawing the 3D picture"):
            picture = write_picture(post, folder / "shell_3d.png", title)
        if picture.path is not None:
            files.append(picture.path.name)
        if picture.warning is not None:
            log.warning(picture.warning)
            summary["warnings"].append(picture.warning)
