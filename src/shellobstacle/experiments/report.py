"""Run the batches and write their files and Markdown sections; ``reproduce`` = all of them."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from mpi4py import MPI

from shellobstacle.checkpoint import Checkpoint
from shellobstacle.config import Config, PenaltySpec, load_config
from shellobstacle.domains import DomainSpec
from shellobstacle.experiments.common import (
    LazyReference,
    exact_solution,
    finish_figure,
    fit_rate,
    write_csv,
)
from shellobstacle.experiments.load import (
    PAPER_BATCH3_LOAD,
    load_study,
    plot_contact_area,
    write_load_study,
)
from shellobstacle.experiments.mesh import (
    mesh_levels,
    mesh_study,
    plot_mesh_study,
    write_mesh_study,
)
from shellobstacle.experiments.penalty import (
    PenaltyStudyOptions,
    penalty_study,
    plot_penalty_study,
    write_penalty_study,
)
from shellobstacle.model import Load
from shellobstacle.pipeline import make_mesh
from shellobstacle.plotting import plot_cross_section
from shellobstacle.results import atomic_write, versions

__all__ = ["SIZES", "reproduce", "run_load", "run_mesh", "run_penalty"]

Say = Callable[[str], Any]
NewtonProgress = Callable[[int, float], Any] | None
PAPER_CONFIG = Path(__file__).parents[1] / "configs" / "paper.toml"
#: gmsh targets ≈ h / 1.34 give largest cell diameters h ≈ 0.0312, 0.0156, 0.0078, 0.0039
GMSH_TARGET = {0.0312: 0.0233, 0.0156: 0.0116, 0.0078: 0.0058, 0.0039: 0.0029}


@dataclass(frozen=True)
class Sizes:
    """Mesh sizes and sweeps of one reproduce mode."""

    batch1_h: tuple[float, ...]
    batch2_base_h: float
    batch2_refinements: int
    batch2_q: tuple[float, ...]
    batch3_h: float
    batch3_central_h: float
    batch3_ell: tuple[float, ...]
    batch3_exponent: float
    solver_h: tuple[float, ...]


SIZES = {
    "fast": Sizes(
        batch1_h=(0.0312, 0.0156),
        batch2_base_h=0.0312 * 3,
        batch2_refinements=3,
        batch2_q=(0.4, 0.5, 0.6, 0.7, 1.0, 1.3),
        batch3_h=0.05,
        batch3_central_h=0.004,
        batch3_ell=(0, 10, 20, 40, 80),
        batch3_exponent=1.5,
        solver_h=(0.1, 0.07),
    ),
    "full": Sizes(
        batch1_h=(0.0312, 0.0078, 0.0039),
        batch2_base_h=0.0312,
        batch2_refinements=4,
        batch2_q=(0.4, 0.5, 0.6, 0.7, 1.0, 1.3),
        batch3_h=0.03,
        batch3_central_h=0.002,
        batch3_ell=(0, 5, 10, 20, 30, 40, 60, 80),
        batch3_exponent=1.5,
        solver_h=(0.1, 0.07, 0.05),
    ),
}


def _fmt(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _table(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    head = "| " + " | ".join(columns) + " |\n|" + "---|" * len(columns) + "\n"
    return head + "\n".join("| " + " | ".join(_fmt(r[c]) for c in columns) + " |" for r in rows)


def run_penalty(
    cfg: Config,
    folder: Path,
    meshes: Sequence[DomainSpec],
    say: Say,
    options: PenaltyStudyOptions | None = None,
    quadratures: Sequence[str] = ("gauss", "vertex"),
    batch4: list[dict[str, Any]] | None = None,
    checkpoint: Checkpoint | None = None,
    newton_progress: NewtonProgress = None,
) -> str:
    """Batch 1 on each mesh, for each penalty quadrature; returns the report section.

    With a ``batch4`` list, the vertex-penalty solutions are also compared with the exact
    nodal VI solution on the same mesh, and the rows are appended to it. With ``checkpoint``
    every κ is recorded (keys: mesh number and target size, quadrature, q) and recorded κ
    are not solved again.
    """
    opts = options or PenaltyStudyOptions()
    cp = checkpoint or Checkpoint(None)
    text = ["## Batch 1: κ → 0 on a fixed mesh (Theorems 5.1, 7.1)", ""]
    text.append(
        f"κ = h^q with q = {opts.start:g}, {opts.start + opts.step:g}, …; the Cauchy differences "
        f"‖ζ_{{h^{{q_n}}}} − ζ_{{h^{{q_{{n+1}}}}}}‖ are computed until they fall below "
        f"{opts.tol:g}. "
        "Theorem 7.1 bounds ‖ζ − ζ_κ‖_{V_M} by C√κ, so the differences should decay at least like "
        "√κ (slope 0.5 against κ; the paper plots them against √(h^{q_n})/10)."
    )
    text.append("")
    summary = []
    for i, spec in enumerate(meshes):
        mesh = make_mesh(spec)
        studies = []
        for quadrature in quadratures:
            disc = dataclasses.replace(cfg.discretization, penalty_quadrature=quadrature)
            reference = None
            if batch4 is not None and quadrature == "vertex":
                reference = LazyReference(_exact(cfg, mesh, disc, say, "the h-mesh"))
            s = penalty_study(
                cfg.shell,
                mesh,
                disc,
                opts,
                cfg.solver,
                say,
                reference,
                cp.scope(f"batch1_mesh{i}_h{spec.h:.10g}_{quadrature}"),
                newton_progress,
            )
            if batch4 is not None:
                batch4.extend(s.reference_rows)
            write_penalty_study(s, folder)
            studies.append(s)
            summary.append(
                {
                    "h": s.h,
                    "dofs": s.dofs,
                    "penalty": quadrature,
                    "differences": len(s.rows),
                    "last q": s.rows[-1]["q_m"] if s.rows else float("nan"),
                    "last error_VM": s.rows[-1]["error_VM"] if s.rows else float("nan"),
                    "reached tol": s.reached_tol,
                    "rate vs κ": s.decay_rate(),
                    "Newton per κ": s.mean_newton(),
                    "Newton steps": "/".join(str(r["newton"]) for r in s.solves),
                    "seconds": s.seconds,
                }
            )
            text += [
                f"### h = {s.h:.4f}, {quadrature} penalty ({s.dofs} dofs)",
                "",
                _table(s.rows, ("iteration", "q_n", "q_m", "error_VM", "error_H1")),
                "",
            ]
        png = folder / f"batch1_h{studies[0].h:.4f}.png"
        if MPI.COMM_WORLD.rank == 0:
            plot_penalty_study(studies, png, opts.tol)
        text += [f"![batch 1, h = {studies[0].h:.4f}]({png.name})", ""]
    text += [
        "### Summary",
        "",
        _table(summary, list(summary[0])),
        "",
        "`rate vs κ` is the fitted slope of log(error_VM) against log κ_n; `Newton per κ` "
        "the mean Newton steps per κ after the first (warm starts), `Newton steps` those of "
        "every κ. With Gauss points the κ near h² takes more: there the penetration (≈ κλ) "
        "falls to the gap's curvature within a cell and the active set thins from six to at "
        "most three points per contact cell (docs/performance.md, eighth session); the "
        "vertex penalty's active set does not move.",
        "",
    ]
    return "\n".join(text)


def run_mesh(
    cfg: Config,
    folder: Path,
    base: DomainSpec,
    refinements: int,
    q_values: Sequence[float],
    say: Say,
    tol: float = 2e-6,
    batch4: list[dict[str, Any]] | None = None,
    checkpoint: Checkpoint | None = None,
    newton_progress: NewtonProgress = None,
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
    levels = mesh_levels(
        cfg.shell, make_mesh(base), refinements, cfg.discretization, cfg.solver, say, cp
    )
    reference = None
    if batch4 is not None:
        where = f"the finest mesh (h = {levels[-1].h:.4g})"
        reference = LazyReference(_exact(cfg, levels[-1].mesh, cfg.discretization, say, where))
    summary = []
    for q in q_values:
        s = mesh_study(
            levels,
            q,
            tol,
            say,
            reference,
            checkpoint=cp,
            newton_progress=newton_progress,
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
            _table(s.rows, ("h_1", "h_2", "error_VM", "error_H1")),
            "",
            f"![batch 2, q = {q:g}]({png.name})",
            "",
        ]
    for level in levels:  # the sweep is complete: no later step starts from these
        cp.drop_vector(level.saved)
    text += ["### Summary", "", _table(summary, list(summary[0])), ""]
    return "\n".join(text)


def _exact(cfg: Config, mesh: Any, disc: Any, say: Say, where: str) -> Callable[[], Any]:
    """The batch-4 reference on ``mesh``, to be computed when a step first needs it.

    It is not recorded: a resumed run recomputes it (deterministically, the same numbers)
    only if a step that compares with it is still to be solved.
    """

    def make() -> Any:
        reference, r = exact_solution(cfg.shell, mesh, disc)
        say(f"batch 4: exact VI on {where}: {r.iterations} steps, KKT {r.kkt}")
        return reference

    return make


def write_batch4(
    folder: Path, penalty_rows: list[dict[str, Any]], mesh_rows: list[dict[str, Any]]
) -> str:
    """Batch 4 files (CSV, figures) and report section: errors against exact solutions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    write_csv(
        folder / "batch4_penalty_error.csv", penalty_rows, ("h", "kappa", "error_VM", "error_H1")
    )
    write_csv(folder / "batch4_mesh_error.csv", mesh_rows, ("q", "h", "error_VM", "error_H1"))
    text = [
        "## Batch 4: errors against the exact discrete solution (beyond the paper)",
        "",
        "The exact solution ζ^h of the discrete variational inequality (constraint g ≥ 0 at "
        "the vertices, P1) is computed by the active-set solver and verified by its KKT "
        "conditions. The paper could only show Cauchy differences; here the penalty error "
        "‖ζ_κ^h − ζ^h‖ (vertex penalty, the same constraint) is measured directly, and the "
        "h-convergence of the penalized solutions towards the exact solution on the finest "
        "nested mesh. Caveat: the reference is only one refinement finer than the last "
        "measured mesh, which biases the fitted h-rates upward; the rates in κ are not "
        "affected (same mesh).",
        "",
    ]
    summary = []
    by_h: dict[float, list[dict[str, Any]]] = {}
    for r in penalty_rows:
        by_h.setdefault(r["h"], []).append(r)
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for h, rows in by_h.items():
        k = [r["kappa"] for r in rows]
        e = [r["error_VM"] for r in rows]
        ax.loglog(k, e, "o-", label=f"h = {h:.4f}, V_M")
        ax.loglog(k, [r["error_H1"] for r in rows], "s--", label=f"h = {h:.4f}, full H¹")
        # fit where the error is above the round-off of the comparison
        keep = [i for i, v in enumerate(e) if v > 1e-12]
        summary.append(
            {
                "h": h,
                "fitted rate in κ (V_M)": fit_rate([k[i] for i in keep], [e[i] for i in keep]),
                "Theorem 7.1": 0.5,
                "κ values": len(rows),
            }
        )
    png1 = finish_figure(
        fig,
        ax,
        folder / "batch4_penalty_error.png",
        "κ",
        "‖ζ_κ − ζ^h‖ (vertex penalty vs exact VI)",
        "Batch 4: penalty error against the exact discrete solution",
    )
    text += [
        _table(summary, list(summary[0])) if summary else "(no rows)",
        "",
        f"![penalty error]({png1.name})",
        "",
    ]
    by_q: dict[float, list[dict[str, Any]]] = {}
    for r in mesh_rows:
        by_q.setdefault(r["q"], []).append(r)
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    summary = []
    for q, rows in by_q.items():
        rows = rows[:-1]  # the finest level is the reference's own mesh
        h = [r["h"] for r in rows]
        e = [r["error_VM"] for r in rows]
        ax.loglog(h, e, "o-", label=f"q = {q:g}")
        summary.append(
            {"q": q, "fitted rate in h (V_M)": fit_rate(h, e), "Theorem 8.1 bound": 1 - q / 2}
        )
    png2 = finish_figure(
        fig,
        ax,
        folder / "batch4_mesh_error.png",
        "h",
        "‖ζ^h_{h^q} − ζ_ref‖ in V_M",
        "Batch 4: κ = h^q solutions against the exact fine-mesh solution",
    )
    text += [
        _table(summary, list(summary[0])) if summary else "(no rows)",
        "",
        f"![mesh error]({png2.name})",
        "",
    ]
    return "\n".join(text)


def run_load(
    cfg: Config,
    folder: Path,
    domain: DomainSpec,
    values: Sequence[float],
    exponent: float,
    say: Say,
    parameter: str = "ell",
    checkpoint: Checkpoint | None = None,
    newton_progress: NewtonProgress = None,
) -> str:
    """Batch 3 (load sweep); returns the report section.

    With ``checkpoint`` every value is recorded and recorded values are not solved again.
    """
    s = load_study(
        cfg.shell,
        make_mesh(domain),
        cfg.discretization,
        PenaltySpec(exponent=exponent),
        values,
        parameter,
        cfg.solver,
        say,
        (checkpoint or Checkpoint(None)).scope("batch3"),
        newton_progress,
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
        plot_contact_area(s, png_area)
    verdict = "grows" if s.area_increases() else "does NOT grow monotonically"
    return "\n".join(
        [
            "## Batch 3: the contact area as the load grows",
            "",
            f"g_ℓ = −(2ε/25)(−5y1² − 5y2² + (1 + 0.05ℓ)·0.295) on |y| < 0.06; h = {s.h:.4g} "
            f"(refined near the centre), κ = h^{exponent:g} = {s.kappa:.3e}, {s.dofs} dofs. "
            f"The contact area {verdict} with ℓ. Areas are measured on the nodes (lumped "
            "masses of the vertices "
            "with g ≤ 0).",
            "",
            _table(
                s.rows,
                (
                    "ell",
                    "contact_area",
                    "contact_area_projected",
                    "max_violation",
                    "zeta3_min",
                    "newton",
                ),
            ),
            "",
            f"![cross-sections]({png_sections.name})",
            "",
            f"![contact area]({png_area.name})",
            "",
        ]
    )


def run_solvers(
    cfg: Config,
    folder: Path,
    meshes: Sequence[Any],
    q: float,
    say: Say,
    checkpoint: Checkpoint | None = None,
    newton_progress: NewtonProgress = None,
) -> str:
    """Newton against Brezis–Sibony (the paper's section 9); returns the report section.

    With ``checkpoint`` every mesh's row is recorded and recorded meshes are not solved again.
    """
    from shellobstacle.experiments.solvers import compare_solvers, write_solver_comparison

    rows = compare_solvers(
        cfg,
        meshes,
        q,
        progress=say,
        checkpoint=(checkpoint or Checkpoint(None)).scope("solvers"),
        newton_progress=newton_progress,
    )
    out = write_solver_comparison(rows, folder)
    columns = (
        "h",
        "dofs",
        "kappa",
        "newton_iterations",
        "newton_seconds",
        "bs_converged",
        "bs_iterations",
        "bs_seconds",
        "xi",
        "contraction_bound",
        "contraction_observed",
        "relative_l2_difference",
    )
    return "\n".join(
        [
            "## Newton against the Brezis–Sibony iteration (section 9)",
            "",
            f"κ = h^{q:g}; Brezis–Sibony (38) from the linearized start with the automatic step "
            "τ = Ξh⁴ = 2/(1.1 λ_max), λ_max the largest eigenvalue of the all-active Jacobian "
            "against the mass matrix; `contraction_bound` = max|1 − τλ| over the spectrum, "
            "`contraction_observed` the geometric mean of successive L² increment ratios; "
            "`relative_l2_difference` = ‖ψ − ζ_Newton‖_L² / ‖ζ_Newton‖_L².",
            "",
            _table(rows, columns),
            "",
            _solver_verdict(rows, out["slope"]),
            "",
            f"![solvers]({Path(out['png']).name})",
            "",
        ]
    )


def _solver_verdict(rows: Sequence[dict[str, Any]], slope: float) -> str:
    """One honest sentence on how the Brezis–Sibony count grows with h."""
    if not np.isfinite(slope):
        return (
            "No growth rate can be fitted: fewer than two meshes needed Brezis–Sibony "
            "iterations (without contact the linearized start is already the solution)."
        )
    newton = ", ".join(str(r["newton_iterations"]) for r in rows)
    return (
        f"Brezis–Sibony iteration counts grow like h^{slope:.2f} (fitted over the meshes "
        f"that needed iterations); Newton took {newton} steps in total on these meshes."
    )


def _resumed_note(cp: Checkpoint) -> list[str]:
    """A paragraph saying that steps came from the records of an interrupted run, if any."""
    if not cp.stats["loaded"]:
        return []
    return [
        f"Resumed: {cp.stats['loaded']} finished step(s) were taken from the records of an "
        "interrupted run (`steps/`), not recomputed; the times above are this invocation's, "
        "the `seconds` in the tables include the recorded steps' times.",
        "",
    ]


def batch3_config(cfg: Config) -> Config:
    """The paper's configuration with the ℓ-dependent load of batch 3."""
    shell = dataclasses.replace(cfg.shell, load=Load(("0", "0", PAPER_BATCH3_LOAD), {"ell": 0.0}))
    return dataclasses.replace(cfg, shell=shell)


def reproduce(
    folder: Path,
    mode: str,
    say: Say,
    checkpoint: Checkpoint | None = None,
    newton_progress: NewtonProgress = None,
) -> Path:
    """All batches of the paper's section 10 with ``report.md``; returns the report path.

    With ``checkpoint`` every step of every batch is recorded as it finishes, and recorded
    steps (of an interrupted run) are not solved again.
    """
    sizes = SIZES[mode]
    cp = checkpoint or Checkpoint(None)
    kw: dict[str, Any] = {"checkpoint": cp, "newton_progress": newton_progress}
    cfg = load_config(PAPER_CONFIG)
    t0 = time.perf_counter()
    sections, times = [], {}

    def disk(h: float, **kw: Any) -> DomainSpec:
        return DomainSpec("disk", h=GMSH_TARGET.get(h, h / 1.34), radius=0.5, **kw)

    penalty_rows: list[dict[str, Any]] = []
    mesh_rows: list[dict[str, Any]] = []
    t = time.perf_counter()
    batch1_meshes = [disk(h) for h in sizes.batch1_h]
    sections.append(run_penalty(cfg, folder, batch1_meshes, say, batch4=penalty_rows, **kw))
    times["batch 1"] = time.perf_counter() - t
    t = time.perf_counter()
    base = disk(sizes.batch2_base_h)
    sections.append(
        run_mesh(
            cfg,
            folder,
            base,
            sizes.batch2_refinements,
            sizes.batch2_q,
            say,
            batch4=mesh_rows,
            **kw,
        )
    )
    times["batch 2"] = time.perf_counter() - t
    t = time.perf_counter()
    sections.append(
        run_load(
            batch3_config(cfg),
            folder,
            disk(sizes.batch3_h, central_h=sizes.batch3_central_h, central_radius=0.1),
            sizes.batch3_ell,
            sizes.batch3_exponent,
            say,
            **kw,
        )
    )
    times["batch 3"] = time.perf_counter() - t
    sections.append(write_batch4(folder, penalty_rows, mesh_rows))
    t = time.perf_counter()
    sections.append(run_solvers(cfg, folder, [disk(h) for h in sizes.solver_h], 1.5, say, **kw))
    times["solvers"] = time.perf_counter() - t
    total = time.perf_counter() - t0
    v = versions()
    memory = "kept in the process" if v["malloc"] == "kept" else "given back (glibc's policy)"
    head = [
        "# Meixner & Piersanti (2024), section 10, reproduced",
        "",
        f"Mode `{mode}`; total {total:.0f} s ("
        + ", ".join(f"{k} {s:.0f} s" for k, s in times.items())
        + ").",
        "",
        f"Machine: {v['machine']}, {v['cpus']} CPUs, {v['mpi_ranks']} MPI rank(s), freed memory "
        f"{memory}, MUMPS' DGEMMT {v['gemmt']}, heap prefault {v['prefault']}. shellobstacle "
        f"{v['shellobstacle']}, DOLFINx {v['dolfinx']}, PETSc {v['petsc']}, Python {v['python']}; "
        f"{v['date']}.",
        "",
        *_resumed_note(cp),
        f"Problem: {cfg.shell.surface.description}; ω = disk of radius 0.5; ε = 0.001, λ = 0.4, "
        "μ = 0.012; q = (0, 0, 1); load (0, 0, g) with the paper's discontinuous g; P1 for all "
        "components, ζ_3 clamped; each penalized problem solved by Newton's method with an exact "
        "line search, warm-started along κ. h is the largest cell diameter.",
        "",
    ]
    path = folder / "report.md"
    atomic_write(path, "\n".join(head + sections))
    say(f"report written: {path}")
    return path
