"""The assumptions of the theory (MODEL.md §3), evaluated on the user's data and mesh.

Each check reports the extreme value of its quantity, where it occurs, and
whether it passes. The quantities are evaluated exactly (NumPy on the symbolic
derivatives of θ) at the mesh vertices and at the edge midpoints.
"""

from __future__ import annotations

from dataclasses import dataclass

import dolfinx
import numpy as np

from shellobstacle import compat  # noqa: F401
from shellobstacle.model import Shell

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


def _extreme(
    comm, values: np.ndarray, points: np.ndarray, kind: str
) -> tuple[float, tuple[float, float]]:
    """Global min or max of ``values`` and the point where it occurs."""
    if values.size:
        i = int(np.nanargmin(values) if kind == "min" else np.nanargmax(values))
        local = (float(values[i]), (float(points[i, 0]), float(points[i, 1])))
        if np.isnan(values).any():
            j = int(np.argmax(np.isnan(values)))
            local = (float("nan"), (float(points[j, 0]), float(points[j, 1])))
    else:
        local = (np.inf if kind == "min" else -np.inf, (np.nan, np.nan))
    gathered = comm.allgather(local)
    nans = [g for g in gathered if np.isnan(g[0])]
    if nans:
        return nans[0]
    pick = min if kind == "min" else max
    return pick(gathered, key=lambda g: g[0])


def check_assumptions(shell: Shell, mesh: dolfinx.mesh.Mesh) -> list[Check]:
    """Evaluate assumptions 1–4 and 6 of MODEL.md §3 (5, ``|q| = 1``, is enforced by Obstacle)."""
    pts = sample_points(mesh)
    G = shell.surface.geometry_numpy(pts)
    q = np.asarray(shell.obstacle.q)
    eps = shell.material.epsilon
    comm = mesh.comm
    with np.errstate(invalid="ignore", divide="ignore"):
        det_a = np.asarray(G.det_a, float)
        K = np.asarray(G.gaussian_curvature, float)
        theta_q = sum(np.asarray(G.theta[k], float) * q[k] for k in range(3))
        a3_q = sum(np.asarray(G.a3[k], float) * q[k] for k in range(3))
        H = np.asarray(G.mean_curvature, float)
        kmax = np.abs(H) + np.sqrt(np.maximum(H * H - K, 0.0))
        thin = eps * kmax
    rows = [
        (
            "immersion",
            "a = det(a_αβ)",
            det_a,
            "min",
            "min a > 0",
            "θ must be an immersion: a_1, a_2 linearly independent (is θ real and smooth on ω̄?)",
        ),
        (
            "elliptic",
            "K (Gaussian curvature)",
            K,
            "min",
            "min K > 0",
            "the theory needs an elliptic surface (K ≥ K0 > 0): flat or saddle shells are not "
            "elliptic membrane shells",
        ),
        (
            "inside half-space",
            "θ·q",
            theta_q,
            "min",
            "min θ·q > 0",
            "the reference shell must lie strictly inside {x·q > 0}: raise the offset or move "
            "the plane (Lemma 3.1)",
        ),
        (
            "normal towards obstacle",
            "a³·q",
            a3_q,
            "min",
            "min a³·q > 0",
            "a^3·q must stay positive (Theorem 4.3, Lemma 5.1): the shell must not turn its "
            "back on the plane",
        ),
        (
            "thin shell",
            "ε·max|κ_principal|",
            thin,
            "max",
            "max ε|κ| < 1",
            "the half-thickness is too large for the curvature: reduce epsilon",
        ),
    ]
    checks = []
    for name, quantity, values, kind, requirement, hint in rows:
        value, where = _extreme(comm, values, pts, kind)
        ok = bool(np.isfinite(value) and (value < 1.0 if kind == "max" else value > 0.0))
        checks.append(Check(name, quantity, value, where, requirement, ok, hint))
    return checks


def format_checks(checks: list[Check]) -> str:
    """A plain-text table of the checks."""
    lines = [f"{'assumption':<24} {'quantity':<22} {'extreme':>13}  {'at (y1, y2)':<22} verdict"]
    for c in checks:
        at = f"({c.where[0]:+.4f}, {c.where[1]:+.4f})"
        verdict = "pass" if c.passed else f"FAIL ({c.requirement})"
        lines.append(f"{c.name:<24} {c.quantity:<22} {c.value:>13.6g}  {at:<22} {verdict}")
    return "\n".join(lines)


def require(checks: list[Check]) -> None:
    """Raise :class:`AssumptionError` naming every failed check."""
    failed = [c for c in checks if not c.passed]
    if failed:
        msg = "; ".join(
            f"{c.name}: {c.quantity} = {c.value:.6g} at y = ({c.where[0]:.4g}, {c.where[1]:.4g}) "
            f"violates {c.requirement} — {c.hint}"
            for c in failed
        )
        raise AssumptionError(f"the data break the theory's assumptions: {msg}", checks)
