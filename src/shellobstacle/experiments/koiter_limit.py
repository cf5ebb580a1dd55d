"""Koiter's model tends to the membrane model as ε → 0: the V_M distance, the contact areas
and the boundary layer of ζ_3 at the clamped edge.

The membrane problem is the limit of Koiter's when the load and the penalty are proportional
to ε (the paper's are): J_κ/ε then depends on ε only through the bending's ε²/3, so Koiter's
solution ζ_K(ε') at thickness ε' is computed from the configuration's own ε with the bending
energy scaled by (ε'/ε)² (:meth:`PenalizedProblem.set_bending_scale`), one compiled problem
for every ε'. The membrane solution ζ_M is the configuration's, in the same P2 space, with ζ_3
clamped (the paper's discretization); ζ_M with ζ_3 free (the continuous model's L²) is the
reference of the boundary layer, whose width is where ζ_K,3 first reaches half of ζ_M,3 going
inwards from the edge along y2 = 0 (:mod:`.boundary_layer`). Theory: the layer of an elliptic
shell is √ε wide.

The command's study (:func:`study_domain`) coarsens the configuration's mesh to about
:data:`FAST_DOFS` dofs unless ``--full`` asks for the configuration's own sizes.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mpi4py import MPI

import dolfinx
import numpy as np
import ufl

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import Config
from shellobstacle.experiments.boundary_layer import (
    BAND,
    EDGE_WIDTHS,
    distance_to_boundary,
    graded_domain,
    layer_width,
    zeta3_profile,
)
from shellobstacle.experiments.common import (
    finish_figure,
    fit_rate,
    on_its_mesh,
    solve_by,
    write_csv,
)
from shellobstacle.experiments.markdown import table
from shellobstacle.experiments.picture import SolutionPicture
from shellobstacle.io.checkpoint import Checkpoint
from shellobstacle.mesh.domains import GRADED_KINDS, DomainSpec
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.norms import vm_norm
from shellobstacle.post.sections import line_tree, mesh_extent
from shellobstacle.progress import phase
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.spec import Discretization, Shell

__all__ = [
    "FAST_DOFS",
    "KoiterLimit",
    "koiter_limit",
    "run_koiter_limit",
    "study_domain",
    "validate",
]

log = logging.getLogger(__name__)

#: the most dofs (estimated, :func:`~shellobstacle.mesh.resources.estimate`) of the command's
#: mesh without ``--full`` (``examples/paper.toml``: its target h 0.0058 scaled to 0.0149, 116k
#: dofs against 742k)
FAST_DOFS = 120_000

COLUMNS = (
    "epsilon",
    "distance_VM",
    "relative",
    "contact_area_koiter",
    "contact_area_membrane",
    "layer_width",
    "edge_share",
    "zeta3_min",
    "newton",
    "seconds",
)
FREE, CLAMPED = "membrane, ζ_3 free", "membrane, ζ_3 clamped"


@dataclass
class KoiterLimit:
    """Rows per ε' and the ζ_3 profiles near the edge (distance from γ, values)."""

    epsilon: float
    h: float
    edge_h: float
    kappa: float
    dofs: int
    clamping_effect: float = 0.0  # ‖ζ_M(clamped) − ζ_M(free)‖_{V_M}
    membrane_norm: float = 0.0
    rows: list[dict[str, Any]] = field(default_factory=list)
    distance_from_edge: np.ndarray = field(default_factory=lambda: np.zeros(0))
    #: ζ_3 along y2 = 0 near the edge: the membrane's (ζ_3 free, clamped), Koiter's per ε
    membrane_profiles: dict[str, np.ndarray] = field(default_factory=dict)
    profiles: dict[str, np.ndarray] = field(default_factory=dict)
    seconds: float = 0.0

    def distance_rate(self) -> float:
        """Fitted slope of log ‖ζ_K(ε') − ζ_M‖_{V_M} against log ε'."""
        return fit_rate([r["epsilon"] for r in self.rows], [r["distance_VM"] for r in self.rows])

    def width_rate(self) -> float:
        """Fitted slope of log (layer width) against log ε' (where a layer was found)."""
        rows = [r for r in self.rows if math.isfinite(r["layer_width"])]
        return fit_rate([r["epsilon"] for r in rows], [r["layer_width"] for r in rows])


def validate(
    cfg: Config, epsilons: Sequence[float], edge_h: float | None, edge_width: float | None
) -> None:
    """Raise ConfigError for what the experiment cannot use, naming the fix."""
    from shellobstacle.config.loader import ConfigError

    if not epsilons or any(not e > 0 for e in epsilons):
        raise ConfigError(f"--epsilons: expected positive numbers, got {list(epsilons)}")
    if cfg.solver.linear_solver not in ("auto", "direct"):
        raise ConfigError(
            "koiter-limit solves Koiter's model, which needs solver.linear_solver = 'direct'"
        )
    for name, value in (("--edge-h", edge_h), ("--edge-width", edge_width)):
        if value is not None and not value > 0:
            raise ConfigError(f"{name} must be > 0, got {value}")
    if (edge_h or edge_width) and cfg.domain.kind not in GRADED_KINDS:
        raise ConfigError(
            f"--edge-h/--edge-width grade disk, ellipse and polygon meshes, not a "
            f"{cfg.domain.kind!r} domain: leave them out"
        )


def study_domain(
    domain: DomainSpec,
    epsilons: Sequence[float],
    edge_h: float | None = None,
    edge_width: float | None = None,
    full: bool = False,
) -> DomainSpec:
    """The mesh of ``experiment koiter-limit``: ``domain`` graded towards γ
    (:func:`~.boundary_layer.graded_domain`, ``edge_h`` and ``edge_width`` as given); unless
    ``full``, its own sizes (``h``, ``central_h``, ``edge_h``) scaled up alike until, graded
    by default, the estimated dofs of Koiter's P2 are at most :data:`FAST_DOFS` (a mesh file
    as it is)."""
    from shellobstacle.mesh.resources import estimate

    scaled = domain
    while not full and domain.kind != "file":
        e = estimate(graded_domain(scaled, epsilons), "koiter", 2)
        if e is None or e.dofs <= FAST_DOFS:
            break
        scale = max(1.05, math.sqrt(e.dofs / FAST_DOFS))
        sizes = ("h", "central_h", "edge_h")
        scaled = dataclasses.replace(
            scaled, **{k: scale * getattr(scaled, k) for k in sizes if getattr(scaled, k)}
        )
    return graded_domain(scaled, epsilons, edge_h, edge_width)


def koiter_limit(
    shell: Shell,
    mesh: dolfinx.mesh.Mesh,
    epsilons: Sequence[float],
    kappas: Sequence[float],
    newton: NewtonOptions | None = None,
    checkpoint: Checkpoint | None = None,
    draw: Callable[[Postprocessor, float], Any] | None = None,
    discretization: Discretization | None = None,
) -> KoiterLimit:
    """Solve the membrane problem (ζ_3 clamped and free) and Koiter's for every ε' on
    ``mesh`` (P2, ghosted), each by Newton's continuation (``METHODS["newton"]``) along
    ``kappas`` from ζ = 0.

    ``discretization`` (the config's) gives the quadrature and Koiter's bending form and
    interior penalty; the experiment sets what it compares: P2 with the penalty at Gauss
    points, ζ_3 clamped for Koiter and clamped or free for the membrane.
    ``draw(post, ε')`` is called with Koiter's solution for the ε' nearest the shell's own ε
    (on a log scale), if it is solved in this run (not read back)."""
    cp = checkpoint or Checkpoint(None)
    cp.check_mesh(mesh)
    eps = shell.material.epsilon
    t0 = time.perf_counter()
    lo, hi = mesh_extent(mesh, 0)
    d = np.linspace(0.0, BAND * (hi - lo), 801)
    points = np.zeros((len(d), 3))
    points[:, 0] = hi - d
    tree = line_tree(mesh, "y1", 0.0)

    h, options = mesh_size(mesh), on_its_mesh(newton)

    def solve(problem: PenalizedProblem) -> list[Any]:
        return solve_by("newton", problem, h, kappas, options).steps

    p2 = dataclasses.replace(
        discretization or Discretization(), degree=2, penalty_quadrature="gauss"
    )
    membrane = {}
    for transverse in ("clamped", "free"):
        m = dataclasses.replace(shell, model="membrane")
        problem = PenalizedProblem(m, mesh, dataclasses.replace(p2, transverse=transverse))
        solve(problem)
        membrane[transverse] = problem
    zeta_m = membrane["clamped"].zeta
    area_m = Postprocessor(membrane["clamped"]).contact()["contact_area"]
    study = KoiterLimit(eps, h, 0.0, kappas[-1], membrane["clamped"].num_dofs)
    study.membrane_norm = vm_norm(zeta_m)
    study.clamping_effect = vm_norm(zeta_m - membrane["free"].zeta)
    study.distance_from_edge = d
    study.membrane_profiles = {
        FREE: zeta3_profile(membrane["free"], points, tree),
        CLAMPED: zeta3_profile(membrane["clamped"], points, tree),
    }
    log.info(
        f"koiter-limit: membrane solutions ({study.dofs} dofs), contact area {area_m:.6g}, "
        f"clamping ζ_3 changes ζ_M by {study.clamping_effect:.3e} in V_M"
    )
    koiter = PenalizedProblem(
        dataclasses.replace(shell, model="koiter"),
        mesh,
        dataclasses.replace(p2, transverse="clamped"),
    )
    to_boundary = distance_to_boundary(mesh)

    def near(value: float) -> Any:  # 1 on the cells within EDGE_WIDTHS √ε of γ, else 0
        return ufl.conditional(ufl.lt(to_boundary, EDGE_WIDTHS * math.sqrt(value)), 1.0, 0.0)

    drawn = min(epsilons, key=lambda e: abs(math.log(e / eps))) if epsilons else None
    for value in epsilons:
        key = f"eps{value:.10g}"
        record = cp.load(key)
        tag = " (recorded)"
        if record is None:
            tag = ""
            ts = time.perf_counter()
            koiter.set_bending_scale((value / eps) ** 2)
            koiter.zeta.x.array[:] = 0.0
            with phase(f"koiter-limit: ε = {value:.3g}"):
                steps = solve(koiter)
            post = Postprocessor(koiter)
            profile = zeta3_profile(koiter, points, tree)
            error = koiter.zeta - zeta_m
            distance = vm_norm(error)
            row = {
                "epsilon": value,
                "distance_VM": distance,
                "relative": distance / study.membrane_norm,
                "contact_area_koiter": post.contact()["contact_area"],
                "contact_area_membrane": area_m,
                "layer_width": layer_width(d, profile, study.membrane_profiles[FREE]),
                "edge_share": (vm_norm(near(value) * error) / distance) ** 2,
                "zeta3_min": post.zeta3_range()[0],
                "newton": sum(s.newton.iterations for s in steps),
                "seconds": time.perf_counter() - ts,
            }
            record = {"row": row, "profile": profile}
            cp.save(key, record)
            if draw is not None and value == drawn:
                draw(post, value)
        study.rows.append(record["row"])
        study.profiles[f"Koiter, ε = {value:.3g}"] = np.asarray(record["profile"], dtype=float)
        r = record["row"]
        log.info(
            f"koiter-limit: ε = {value:.3g}: ‖ζ_K − ζ_M‖ = {r['distance_VM']:.4e}, contact area "
            f"{r['contact_area_koiter']:.6g}, layer width {r['layer_width']:.3g}{tag}"
        )
    study.seconds = time.perf_counter() - t0
    return study


def plot_distance(study: KoiterLimit, path: Path) -> Path:
    """‖ζ_K(ε) − ζ_M‖_{V_M} and the layer width against ε (log-log), with √ε for reference."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    e = np.array([r["epsilon"] for r in study.rows])
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    ax.loglog(
        e,
        [r["distance_VM"] for r in study.rows],
        "o-",
        label=f"‖ζ_K − ζ_M‖_V_M (slope {study.distance_rate():.2f})",
    )
    w = np.array([r["layer_width"] for r in study.rows])
    if np.isfinite(w).any():
        ax.loglog(e, w, "s--", label=f"layer width (slope {study.width_rate():.2f})")
        k = int(np.flatnonzero(np.isfinite(w))[-1])
        ax.loglog(e, w[k] * np.sqrt(e / e[k]), ":", color="0.4", label="∝ √ε")
    if not np.isfinite(w).all():  # no layer: ζ_K,3 never reaches half the membrane's ζ_3
        ax.plot(
            e[~np.isfinite(w)],
            np.full(int((~np.isfinite(w)).sum()), 0.04),
            "x",
            color="C1",
            transform=ax.get_xaxis_transform(),
            label="no layer width: ζ_K,3 never reaches half of ζ_M,3 (bending dominates)",
        )
    return finish_figure(fig, ax, path, "ε", "", "Koiter → membrane as ε → 0")


def plot_layer(study: KoiterLimit, path: Path) -> Path:
    """ζ_3 against the distance from the clamped edge along y2 = 0."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    colors = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, len(study.rows)))
    for (label, values), color in zip(study.profiles.items(), colors, strict=False):
        ax.plot(study.distance_from_edge, values, color=color, lw=1.4, label=label)
    for label, style in ((FREE, "k--"), (CLAMPED, "k:")):
        ax.plot(
            study.distance_from_edge, study.membrane_profiles[label], style, lw=1.2, label=label
        )
    ax.set_xscale("symlog", linthresh=max(study.edge_h, 1e-4))
    return finish_figure(
        fig, ax, path, "distance from the edge (y2 = 0)", "ζ_3", "ζ_3 at the clamped edge", False
    )


def run_koiter_limit(
    cfg: Config,
    folder: Path,
    domain: DomainSpec,
    epsilons: Sequence[float],
    checkpoint: Checkpoint | None = None,
) -> str:
    """The experiment on ``cfg``'s shell and ``domain`` (graded towards γ); the report section."""
    mesh = make_mesh(domain, ghosted=True)
    kappas = cfg.penalty.ladder(mesh_size(mesh))
    cp = (checkpoint or Checkpoint(None)).scope("koiter_limit")
    picture = SolutionPicture(cfg, folder / "koiter_limit_shell_3d.png")

    def draw(post: Postprocessor, value: float) -> None:
        picture.draw(post, f"Koiter's model: the deformed shell over the plane at ε = {value:.3g}")

    s = koiter_limit(cfg.shell, mesh, epsilons, kappas, cfg.solver, cp, draw, cfg.discretization)
    s.edge_h = domain.edge_h or s.h
    write_csv(folder / "koiter_limit.csv", s.rows, COLUMNS)
    png_d, png_l = folder / "koiter_limit.png", folder / "koiter_limit_layer.png"
    if MPI.COMM_WORLD.rank == 0:
        plot_distance(s, png_d)
        plot_layer(s, png_l)
    drawn = picture.markdown("Koiter's solution in 3D")
    return "\n".join([*_report(s, domain), "", f"![distance]({png_d.name})", "", *drawn])


def _report(s: KoiterLimit, domain: DomainSpec) -> list[str]:
    near = min(s.rows, key=lambda r: r["epsilon"])
    smallest = near["epsilon"]
    resolved = (domain.edge_h or s.h) <= 0.25 * math.sqrt(smallest)
    return [
        "## Koiter's model and the membrane limit",
        "",
        "Koiter's solution ζ_K(ε) on the configuration's shell for ε = "
        + ", ".join(f"{r['epsilon']:.3g}" for r in s.rows)
        + f", load and penalty ∝ ε, against the membrane solution ζ_M (ε = {s.epsilon:g}; "
        "independent of ε), both P2 on one mesh graded towards the clamped edge: largest cell "
        f"{s.h:.3g}, {domain.edge_h or s.h:.3g} within {domain.edge_width or 0:.3g} of γ, "
        f"{s.dofs} dofs, κ = {s.kappa:.3e}. The layer of ζ_3 is √ε = {math.sqrt(smallest):.3g} "
        f"wide at the smallest ε: {'resolved' if resolved else 'NOT resolved'} by the "
        "edge cells (at most a quarter of its width).",
        "",
        table(s.rows, COLUMNS[:-1]),
        "",
        f"‖ζ_K − ζ_M‖_V_M falls like ε^{s.distance_rate():.2f} (fitted over all ε); "
        f"‖ζ_M‖_V_M = {s.membrane_norm:.4g}. The layer width (where ζ_K,3 first reaches half of "
        f"the membrane's ζ_3 going inwards) grows like ε^{s.width_rate():.2f} (theory for an "
        "elliptic shell: 0.5); NaN where ζ_K,3 never reaches it near the edge (bending "
        "dominates).",
        "",
        "The paper clamps ζ_3 of the membrane problem, which has no boundary condition in "
        "L²: here clamping changes ζ_M by "
        f"{s.clamping_effect:.3e} in V_M ({s.clamping_effect / s.membrane_norm:.2e} of its "
        "norm), and Koiter's ζ_3, clamped by the model, reaches the membrane's within a layer "
        f"that narrows with ε ({near['layer_width']:.3g} at ε = {near['epsilon']:.3g}): "
        "clamping the membrane's ζ_3 imitates that layer within one cell, which "
        "costs the clamping effect above. At ε = "
        f"{smallest:.3g}, {100 * near['edge_share']:.2g} % of ‖ζ_K − ζ_M‖²_V_M lies within "
        f"{EDGE_WIDTHS:g}√ε of γ (`edge_share`): the rest is in the interior, where "
        "Koiter's ζ_3 ∈ H² cannot follow the jumps of the membrane's ζ_3 ∈ L² (the load's "
        "discontinuity, the contact boundary).",
        "",
        "![ζ_3 near the edge](koiter_limit_layer.png)",
    ]
