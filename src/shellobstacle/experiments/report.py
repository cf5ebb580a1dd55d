"""Run the batches and write their files and Markdown sections; ``reproduce`` = all of them."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mpi4py import MPI

from shellobstacle.config import Config, PenaltySpec, load_config
from shellobstacle.domains import DomainSpec
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


SIZES = {
    "fast": Sizes(
        (0.0312, 0.0156),
        0.0312 * 3,
        3,
        (0.4, 0.5, 0.6, 0.7, 1.0, 1.3),
        0.05,
        0.004,
        (0, 10, 20, 40, 80),
        1.5,
    ),
    "full": Sizes(
        (0.0312, 0.0078, 0.0039),
        0.0312,
        4,
        (0.4, 0.5, 0.6, 0.7, 1.0, 1.3),
        0.03,
        0.002,
        (0, 5, 10, 20, 30, 40, 60, 80),
        1.5,
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
) -> str:
    """Batch 1 on each mesh, for each penalty quadrature; returns the report section."""
    opts = options or PenaltyStudyOptions()
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
    for spec in meshes:
        mesh = make_mesh(spec)
        studies = []
        for quadrature in quadratures:
            disc = dataclasses.replace(cfg.discretization, penalty_quadrature=quadrature)
            s = penalty_study(cfg.shell, mesh, disc, opts, cfg.solver, say)
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
        "the mean Newton steps per κ after the first (warm starts).",
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
) -> str:
    """Batch 2 on nested meshes for each q; returns the report section."""
    text = [
        "## Batch 2: h → 0 with κ = h^q (Theorem 8.1)",
        "",
        f"Nested meshes (uniform refinement of a disk mesh, {refinements} times); the coarse "
        "solution is interpolated exactly into the fine space. Theorem 8.1 bounds the error by "
        "C h (1 + 1/√κ) = O(h^{1 − q/2}).",
        "",
    ]
    levels = mesh_levels(
        cfg.shell, make_mesh(base), refinements, cfg.discretization, cfg.solver, say
    )
    summary = []
    for q in q_values:
        s = mesh_study(levels, q, tol, say)
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
    text += ["### Summary", "", _table(summary, list(summary[0])), ""]
    return "\n".join(text)


def run_load(
    cfg: Config,
    folder: Path,
    domain: DomainSpec,
    values: Sequence[float],
    exponent: float,
    say: Say,
    parameter: str = "ell",
) -> str:
    """Batch 3 (load sweep); returns the report section."""
    s = load_study(
        cfg.shell,
        make_mesh(domain),
        cfg.discretization,
        PenaltySpec(exponent=exponent),
        values,
        parameter,
        cfg.solver,
        say,
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


def batch3_config(cfg: Config) -> Config:
    """The paper's configuration with the ℓ-dependent load of batch 3."""
    shell = dataclasses.replace(cfg.shell, load=Load(("0", "0", PAPER_BATCH3_LOAD), {"ell": 0.0}))
    return dataclasses.replace(cfg, shell=shell)


def reproduce(folder: Path, mode: str, say: Say) -> Path:
    """All batches of the paper's section 10 with ``report.md``; returns the report path."""
    sizes = SIZES[mode]
    cfg = load_config(PAPER_CONFIG)
    t0 = time.perf_counter()
    sections, times = [], {}

    def disk(h: float, **kw: Any) -> DomainSpec:
        return DomainSpec("disk", h=GMSH_TARGET.get(h, h / 1.34), radius=0.5, **kw)

    t = time.perf_counter()
    sections.append(run_penalty(cfg, folder, [disk(h) for h in sizes.batch1_h], say))
    times["batch 1"] = time.perf_counter() - t
    t = time.perf_counter()
    sections.append(
        run_mesh(
            cfg, folder, disk(sizes.batch2_base_h), sizes.batch2_refinements, sizes.batch2_q, say
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
        )
    )
    times["batch 3"] = time.perf_counter() - t
    total = time.perf_counter() - t0
    v = versions()
    head = [
        "# Meixner & Piersanti (2024), section 10, reproduced",
        "",
        f"Mode `{mode}`; total {total:.0f} s ("
        + ", ".join(f"{k} {s:.0f} s" for k, s in times.items())
        + ").",
        "",
        f"Machine: {v['machine']}, {v['cpus']} CPUs, {v['mpi_ranks']} MPI rank(s). shellobstacle "
        f"{v['shellobstacle']}, DOLFINx {v['dolfinx']}, PETSc {v['petsc']}, Python {v['python']}; "
        f"{v['date']}.",
        "",
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
