"""The assumptions of the theory (docs/model.md §3, listed under "The obstacle problem" of the
model page), evaluated on the user's data and mesh.

Each check reports the extreme value of its quantity, where it occurs, and
whether it passes. The quantities are evaluated exactly (NumPy on the symbolic
derivatives of θ) at the mesh vertices and at the edge midpoints.
"""

from __future__ import annotations

from dataclasses import dataclass

from mpi4py import MPI  # noqa: F401  (MPI before PETSc and DOLFINx)

import dolfinx
import numpy as np

from shellobstacle.checks.finiteness import Failure, first_failure, require_finite
from shellobstacle.geometry.surface import Geometry
from shellobstacle.obstacle import Obstacle, from_spec
from shellobstacle.spec import Shell

__all__ = ["AssumptionError", "Check", "check_assumptions", "format_checks", "sample_points"]


@dataclass(frozen=True)
class Check:
    """One assumption: its quantity's extreme value, where it occurs, and the verdict."""

    name: str
    quantity: str
    value: float
    where: tuple[float, float]
    requirement: str
    passed: bool
    hint: str


class AssumptionError(ValueError):
    """The data violate an assumption of the theory; ``checks`` holds the whole table."""

    def __init__(self, message: str, checks: list[Check]) -> None:
        super().__init__(message)
        self.checks = checks


def sample_points(mesh: dolfinx.mesh.Mesh) -> np.ndarray:
    """Geometry nodes and edge midpoints of the local mesh part (n × 2)."""
    x = mesh.geometry.x[:, :2]
    tdim = mesh.topology.dim
    mesh.topology.create_entities(1)
    mesh.topology.create_connectivity(1, tdim)
    num_edges = mesh.topology.index_map(1).size_local + mesh.topology.index_map(1).num_ghosts
    nodes = dolfinx.mesh.entities_to_geometry(mesh, 1, np.arange(num_edges, dtype=np.int32))
    mids = 0.5 * (x[nodes[:, 0]] + x[nodes[:, 1]])
    return np.vstack([x, mids])


CHUNK = 2**16
"""Points evaluated at a time: the geometry's temporaries stay small and are reused (at 2.6 M
points at once they would be ≈ 1 GB of fresh memory, slow to touch on some machines)."""

Extreme = tuple[float, tuple[float, float]]


def _pick(candidates: list[Extreme], kind: str) -> Extreme:
    """The first NaN or infinity of ``candidates`` if any, else the smallest (``min``) or
    largest value (the first one on ties)."""
    bad = [c for c in candidates if not np.isfinite(c[0]) and np.isfinite(c[1][0])]
    if bad:
        return bad[0]
    return (min if kind == "min" else max)(candidates, key=lambda c: c[0])


def _local_extreme(values: np.ndarray, points: np.ndarray, kind: str) -> Extreme:
    """Min or max of ``values`` and the point where it occurs (the first NaN or infinity, if
    any)."""
    if not values.size:
        return (np.inf if kind == "min" else -np.inf, (np.nan, np.nan))
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.argmax(bad))
        return (float(values[i]), (float(points[i, 0]), float(points[i, 1])))
    i = int(np.argmin(values) if kind == "min" else np.argmax(values))
    return (float(values[i]), (float(points[i, 0]), float(points[i, 1])))


def _quantities(shell: Shell, obstacle: Obstacle, G: Geometry, n: int) -> list[np.ndarray]:
    """det(a_αβ), K, θ·q, a³·q and ε·max|κ_principal| from ``G`` evaluated at ``n`` points."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        det_a = np.asarray(G.det_a, float)
        K = np.asarray(G.gaussian_curvature, float)
        theta_q = np.asarray(obstacle.reference_gap(G), float)  # g(θ) (a plane's θ·q)
        a3_q = np.asarray(obstacle.c(G)[2], float)  # ∇g·a³ (a plane's a³·q)
        H = np.asarray(G.mean_curvature, float)
        kmax = np.abs(H) + np.sqrt(np.maximum(H * H - K, 0.0))
    return [
        np.broadcast_to(v, (n,)) for v in (det_a, K, theta_q, a3_q, shell.material.epsilon * kmax)
    ]


ROWS = [
    (
        "immersion",
        "a = det(a_αβ)",
        "min",
        "min a > 0",
        "θ must be an immersion: a_1, a_2 linearly independent (is θ real and smooth on ω̄?)",
    ),
    (
        "elliptic",
        "K (Gaussian curvature)",
        "min",
        "min K > 0",
        "the membrane model needs an elliptic surface (K ≥ K0 > 0), and flat or saddle shells "
        'are not elliptic: set model.kind = "koiter" (membrane and bending, any thin shell)',
    ),
    (
        "inside half-space",
        "θ·q",
        "min",
        "min θ·q > 0",
        "the reference shell must lie strictly inside {x·q > 0}: move the shell or the plane "
        "(Lemma 3.1)",
    ),
    (
        "normal towards obstacle",
        "a³·q",
        "min",
        "min a³·q > 0",
        "a^3·q must stay positive (Theorem 4.3, Lemma 5.1): the shell must not turn its "
        "back on the plane",
    ),
    (
        "thin shell",
        "ε·max|κ_principal|",
        "max",
        "max ε|κ| < 1",
        "the half-thickness is too large for the curvature: reduce epsilon",
    ),
]
"""name, quantity, extreme sought, requirement and hint of each check (order of _quantities)."""


def _half_space_hint(shell: Shell, hint: str) -> str:
    """For the caps, which way to move ``surface.offset``: θ_3 = … − offset, so θ·q falls by
    q_3 for each unit of offset, and a shell below the plane needs a smaller offset when
    q_3 > 0 (a larger one when q_3 < 0)."""
    q3 = shell.obstacle.q[2]
    if shell.surface.name not in ("spherical_cap", "ellipsoid_cap") or q3 == 0.0:
        return hint
    way = "lower" if q3 > 0 else "raise"
    return (
        "the reference shell must lie strictly inside {x·q > 0}: "
        f"{way} surface.offset (it shifts the cap along −e_3) or move the plane (Lemma 3.1)"
    )


def check_assumptions(shell: Shell, mesh: dolfinx.mesh.Mesh) -> list[Check]:
    """Evaluate assumptions 1–4 and 6 of docs/model.md §3 (5, ``|q| = 1``, is enforced by Obstacle);
    for Koiter's model the Gaussian curvature is reported but not required (§8).

    Raises:
        ExpressionError: θ, its derivatives or the load are not finite at a point of the mesh
            (:mod:`shellobstacle.checks.finiteness`): the assumptions are then meaningless.
    """
    pts = sample_points(mesh)
    obstacle = from_spec(shell.obstacle, shell.material.epsilon)
    found: list[list[Extreme]] = [[] for _ in ROWS]
    largest: list[Extreme] = []  # of g(θ): below 0 everywhere, the shell is on the wrong side
    failures: list[Failure | None] = []
    for start in range(0, max(len(pts), 1), CHUNK):
        chunk = pts[start : start + CHUNK]
        G = shell.surface.geometry_numpy(chunk)
        failures.append(first_failure(shell, G, chunk))
        quantities = _quantities(shell, obstacle, G, len(chunk))
        for row, values, found_row in zip(ROWS, quantities, found, strict=True):
            found_row.append(_local_extreme(values, chunk, row[2]))
        largest.append(_local_extreme(quantities[2], chunk, "max"))
    require_finite(shell, failures, mesh.comm)
    g_max = _pick(mesh.comm.allgather(_pick(largest, "max")), "max")[0]
    checks = []
    for (name, quantity, kind, requirement, hint), local in zip(_rows(shell), found, strict=True):
        if name == "inside half-space":
            hint = _half_space_hint(shell, hint)
        value, where = _pick(mesh.comm.allgather(_pick(local, kind)), kind)
        ok = bool(np.isfinite(value) and (value < 1.0 if kind == "max" else value > 0.0))
        if not ok:
            requirement, hint = _gap_fix(shell, name, value, g_max, requirement, hint)
        if name == "elliptic" and shell.model == "koiter":
            # Koiter's model needs an immersion and a thin shell, not K > 0 (docs/model.md §8)
            requirement, ok = "none (Koiter's model)", bool(np.isfinite(value))
        checks.append(Check(name, quantity, value, where, requirement, ok, hint))
    if shell.obstacle.kind != "plane":
        convex = obstacle.convex
        checks.append(
            Check(
                "convex admissible set", "1 yes, 0 no, nan unknown",
                np.nan if convex is None else float(convex), (np.nan, np.nan),
                "none (the paper's theory: convex; otherwise a solution may be a local one)",
                True, "inside a ball or a cylinder, or a plane: convex; outside: not",
            )
        )  # fmt: skip
    return checks


def _gap_fix(
    shell: Shell, name: str, value: float, g_max: float, requirement: str, hint: str
) -> tuple[str, str]:
    """The requirement and the fix of a failed row of a curved obstacle's gap: a ``g`` or a
    ``∇g`` that is not finite says so; a shell wholly on the wrong side of a ball or a
    cylinder (``g(θ) < 0`` everywhere, largest ``g_max``) names ``obstacle.side``."""
    o = shell.obstacle
    if o.kind == "plane" or name not in ("admissible reference", "normal towards obstacle"):
        return requirement, hint
    what = "g(θ)" if name == "admissible reference" else "∇g·a³"
    if not np.isfinite(value):
        if o.kind == "expression":
            why = (
                "obstacle.g has no finite value or gradient there (a logarithm or a root of a "
                "negative number, a division by zero?): change obstacle.g"
            )
        else:
            axis = "centre" if o.kind == "sphere" else "axis"
            why = f"∇g is not defined at the {o.kind}'s {axis}: move the {o.kind}"
        return f"{what} finite", f"{what} = {value} on the reference shell: {why}"
    if name == "admissible reference" and o.kind in ("sphere", "cylinder") and g_max < 0:
        where = "inside" if o.side == "outside" else "outside"
        return requirement, (
            f"the reference shell lies wholly {where} the {o.kind} (g(θ) ≤ {g_max:.4g} < 0), "
            f"which obstacle.side = {o.side!r} forbids: set obstacle.side = {where!r} to keep "
            f"it {where}, or move the {o.kind}"
        )
    return requirement, hint


def _rows(shell: Shell) -> list[tuple[str, str, str, str, str]]:
    """:data:`ROWS`, with a curved obstacle's gap ``g`` in place of the plane's ``x·q``."""
    if shell.obstacle.kind == "plane":
        return ROWS
    rows = list(ROWS)
    rows[2] = (
        "admissible reference",
        "g(θ)",
        "min",
        "min g(θ) > 0",
        "the reference shell (its contact face) must lie strictly inside {g > 0}, with g and "
        "∇g finite there: move the shell or the obstacle",
    )
    rows[3] = (
        "normal towards obstacle",
        "∇g·a³",
        "min",
        "min ∇g·a³ > 0",
        "∇g·a^3 must stay positive (Theorem 4.3, Lemma 5.1 for a plane): the shell must face "
        "the obstacle",
    )
    return rows


def format_checks(checks: list[Check]) -> str:
    """A plain-text table of the checks."""
    lines = [f"{'assumption':<24} {'quantity':<22} {'extreme':>13}  {'at (y1, y2)':<22} verdict"]
    for c in checks:
        at = f"({c.where[0]:+.4f}, {c.where[1]:+.4f})"
        verdict = "pass" if c.passed else f"FAIL ({c.requirement})"
        if c.passed and c.requirement.startswith("none"):
            verdict = f"not required: {c.requirement[6:-1]}"
        value = c.value + 0.0  # no "-0"
        lines.append(f"{c.name:<24} {c.quantity:<22} {value:>13.6g}  {at:<22} {verdict}")
    lines += [f"{c.name}: {c.hint}" for c in checks if not c.passed]  # the fixes
    return "\n".join(lines)


def require(checks: list[Check]) -> None:
    """Raise :class:`AssumptionError` naming every failed check."""
    failed = [c for c in checks if not c.passed]
    if failed:
        msg = "; ".join(
            f"{c.name}: {c.quantity} = {c.value + 0.0:.6g} at y = ({c.where[0]:.4g}, "
            f"{c.where[1]:.4g}) "
            f"violates {c.requirement} — {c.hint}"
            for c in failed
        )
        raise AssumptionError(f"the data break the theory's assumptions: {msg}", checks)
