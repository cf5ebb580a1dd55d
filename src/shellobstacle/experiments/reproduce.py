"""``shellobstacle reproduce``: every batch of the paper's section 10 and ``report.md``."""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from shellobstacle.config.loader import load_config
from shellobstacle.experiments.adaptive import AdaptiveStudyOptions, run_adaptive
from shellobstacle.experiments.exact import write_batch4
from shellobstacle.experiments.koiter_limit import run_koiter_limit
from shellobstacle.experiments.load import batch3_config, run_load
from shellobstacle.experiments.mesh import run_mesh
from shellobstacle.experiments.penalty import run_penalty
from shellobstacle.experiments.solvers import run_solvers
from shellobstacle.io.checkpoint import Checkpoint
from shellobstacle.io.records import atomic_write, versions
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.progress import phase

__all__ = ["PAPER_CONFIG", "SIZES", "Sizes", "reproduce"]

log = logging.getLogger(__name__)
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
    #: Koiter's limit: ε values, mesh sizes (largest, centre r < 0.1, within edge_width of γ)
    koiter_epsilons: tuple[float, ...]
    koiter_h: tuple[float, float, float, float]
    #: adaptive refinement: first mesh's h, its uniform refinements, the adaptive loop's and
    #: the reference's dofs
    adaptive_h: float = 0.0312
    adaptive_refinements: int = 4
    adaptive_dofs: int = 130_000
    adaptive_reference_dofs: int = 1_000_000


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
        koiter_epsilons=(1e-1, 10**-1.5, 1e-2, 10**-2.5, 1e-3),
        koiter_h=(0.05, 0.015, 0.008, 0.06),
        adaptive_h=0.0312 * 3,
        adaptive_refinements=3,
        adaptive_dofs=12_000,
        adaptive_reference_dofs=100_000,
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
        koiter_epsilons=(1e-1, 10**-1.5, 1e-2, 10**-2.5, 1e-3, 10**-3.5, 1e-4),
        koiter_h=(0.03, 0.0025, 0.0025, 0.04),
    ),
}


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


def reproduce(
    folder: Path,
    mode: str,
    checkpoint: Checkpoint | None = None,
) -> Path:
    """All batches of the paper's section 10 with ``report.md``; returns the report path.

    With ``checkpoint`` every step of every batch is recorded as it finishes, and recorded
    steps (of an interrupted run) are not solved again.
    """
    sizes = SIZES[mode]
    cp = checkpoint or Checkpoint(None)
    kw: dict[str, Any] = {"checkpoint": cp}
    cfg = load_config(PAPER_CONFIG)
    t0 = time.perf_counter()
    sections, times = [], {}

    def disk(h: float, **kw: Any) -> DomainSpec:  # the config's disk at another size
        return dataclasses.replace(cfg.domain, h=GMSH_TARGET.get(h, h / 1.34), **kw)

    penalty_rows: list[dict[str, Any]] = []
    mesh_rows: list[dict[str, Any]] = []
    t = time.perf_counter()
    batch1_meshes = [disk(h) for h in sizes.batch1_h]
    with phase("batch 1 (1/5): κ → 0 on fixed meshes"):
        sections.append(run_penalty(cfg, folder, batch1_meshes, batch4=penalty_rows, **kw))
    times["batch 1"] = time.perf_counter() - t
    t = time.perf_counter()
    base = disk(sizes.batch2_base_h)
    with phase("batch 2 (2/5): nested meshes, κ = h^q"):
        sections.append(
            run_mesh(
                cfg,
                folder,
                base,
                sizes.batch2_refinements,
                sizes.batch2_q,
                batch4=mesh_rows,
                **kw,
            )
        )
    times["batch 2"] = time.perf_counter() - t
    t = time.perf_counter()
    with phase("batch 3 (3/5): the load sweep"):
        sections.append(
            run_load(
                batch3_config(cfg),
                folder,
                disk(sizes.batch3_h, central_h=sizes.batch3_central_h, central_radius=0.1),
                sizes.batch3_ell,
                sizes.batch3_exponent,
                **kw,
            )
        )
    times["batch 3"] = time.perf_counter() - t
    sections.append(write_batch4(folder, penalty_rows, mesh_rows))
    t = time.perf_counter()
    with phase("Newton against Brezis–Sibony (4/5)"):
        solver_meshes = [disk(h) for h in sizes.solver_h]
        sections.append(run_solvers(cfg, folder, solver_meshes, 1.5, **kw))
    times["solvers"] = time.perf_counter() - t
    t = time.perf_counter()
    h, central_h, edge_h, edge_width = sizes.koiter_h
    graded = dataclasses.replace(
        cfg.domain,
        h=h,
        central_h=central_h,
        central_radius=0.1,
        edge_h=edge_h,
        edge_width=edge_width,
    )
    with phase("Koiter's model as ε → 0 (5/5)"):
        sections.append(run_koiter_limit(cfg, folder, graded, sizes.koiter_epsilons, **kw))
    times["koiter"] = time.perf_counter() - t
    t = time.perf_counter()
    study = AdaptiveStudyOptions(
        sizes.adaptive_refinements, sizes.adaptive_reference_dofs, sizes.adaptive_dofs
    )
    sections.append(run_adaptive(cfg, folder, disk(sizes.adaptive_h), study, **kw))
    times["adaptive"] = time.perf_counter() - t
    total = time.perf_counter() - t0
    v = versions()
    tuned = " ".join(f"{k}={value}" for k, value in v["environment"].items()) or "none set"
    head = [
        "# Meixner & Piersanti (2024), section 10, reproduced",
        "",
        f"Mode `{mode}`; total {total:.0f} s ("
        + ", ".join(f"{k} {s:.0f} s" for k, s in times.items())
        + ").",
        "",
        f"Machine: {v['machine']}, {v['cpus']} CPUs, {v['mpi_ranks']} MPI rank(s); process "
        f"tuning: {tuned}. shellobstacle {v['shellobstacle']}, DOLFINx {v['dolfinx']}, PETSc "
        f"{v['petsc']}, Python {v['python']}; {v['date']}.",
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
    log.info(f"report written: {path}")
    return path
