"""Norms of the space V_M = H¹ × H¹ × L² (docs/model.md §2), of functions and of differences.

Every norm is assembled and reduced over the communicator: the same value on every rank.
"""

from __future__ import annotations

from typing import Any

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.geometry
import dolfinx.la
import numpy as np
import ufl

__all__ = ["DifferenceNorms", "h1_norm", "l2_norm", "norms", "vm_norm"]


def _measure(e: Any, mesh: dolfinx.mesh.Mesh | None, quadrature_degree: int | None) -> ufl.Measure:
    """``dx`` on the mesh of ``e`` (or ``mesh``), with a fixed quadrature degree if given."""
    domain = mesh if mesh is not None else ufl.domain.extract_unique_domain(e)
    if domain is None:
        raise ValueError("cannot find the mesh of the expression: pass mesh=...")
    metadata = {} if quadrature_degree is None else {"quadrature_degree": quadrature_degree}
    return ufl.Measure("dx", domain=domain, metadata=metadata)


def _integrate(integrand: Any, dx: ufl.Measure) -> float:
    """``∫ integrand dx`` over the whole distributed mesh (assemble_scalar + allreduce)."""
    form = dolfinx.fem.form(integrand * dx)
    local = dolfinx.fem.assemble_scalar(form)
    return float(form.mesh.comm.allreduce(local, op=MPI.SUM))


def _squares(e: Any) -> tuple[list[Any], list[Any]]:
    """``e_i²`` and ``|∇e_i|²`` for every component of a scalar or vector UFL expression."""
    comps = [e[i] for i in range(ufl.shape(e)[0])] if ufl.shape(e) else [e]
    return [c * c for c in comps], [ufl.inner(ufl.grad(c), ufl.grad(c)) for c in comps]


def l2_norm(
    e: Any, *, mesh: dolfinx.mesh.Mesh | None = None, quadrature_degree: int | None = None
) -> float:
    """``‖e‖_{L²(ω)} = (∫_ω Σ_i e_i² dy)^{1/2}`` of a scalar or vector Function / UFL expression.

    Args:
        e: Function or UFL expression on a mesh (e.g. ``u - v`` or ``u - exact``).
        mesh: The mesh, needed only if ``e`` does not reveal it (constants).
        quadrature_degree: Fixed quadrature degree; ``None`` lets UFL estimate it (exact for
            polynomial integrands, ``+2`` per non-polynomial function otherwise).

    Returns:
        The global norm (the same on every rank).
    """
    values, _ = _squares(e)
    return float(np.sqrt(_integrate(sum(values), _measure(e, mesh, quadrature_degree))))


def h1_norm(
    e: Any, *, mesh: dolfinx.mesh.Mesh | None = None, quadrature_degree: int | None = None
) -> float:
    """Full ``‖e‖_{H¹(ω)} = (∫_ω Σ_i (e_i² + |∇e_i|²) dy)^{1/2}`` (value plus gradient).

    Args:
        e: Function or UFL expression on a mesh.
        mesh: The mesh, needed only if ``e`` does not reveal it.
        quadrature_degree: Fixed quadrature degree (``None``: UFL's estimate).

    Returns:
        The global norm.
    """
    values, grads = _squares(e)
    total = _integrate(sum(values) + sum(grads), _measure(e, mesh, quadrature_degree))
    return float(np.sqrt(total))


def vm_norm(
    e: Any, *, mesh: dolfinx.mesh.Mesh | None = None, quadrature_degree: int | None = None
) -> float:
    """``‖e‖_{V_M} = (Σ_α ‖e_α‖²_{H¹(ω)} + ‖e_3‖²_{L²(ω)})^{1/2}`` (:eq:`vm-norm`).

    Args:
        e: Vector Function or UFL expression with three covariant components.
        mesh: The mesh, needed only if ``e`` does not reveal it.
        quadrature_degree: Fixed quadrature degree (``None``: UFL's estimate).

    Returns:
        The global norm.

    Raises:
        ValueError: If ``e`` does not have three components.
    """
    if ufl.shape(e) != (3,):
        raise ValueError(f"vm_norm needs a 3-vector (η_1, η_2, η_3), got shape {ufl.shape(e)}")
    values, grads = _squares(e)
    total = _integrate(sum(values) + grads[0] + grads[1], _measure(e, mesh, quadrature_degree))
    return float(np.sqrt(total))


def norms(
    u: Any,
    v: Any | None = None,
    *,
    mesh: dolfinx.mesh.Mesh | None = None,
    quadrature_degree: int | None = None,
) -> dict[str, float]:
    """The L², H¹ and V_M norms of ``u − v`` (of ``u`` if ``v`` is None).

    ``u`` and ``v`` must live on the same mesh (interpolate a coarse solution into the fine
    space first: nested meshes make that exact, docs/model.md §7 batch 2).

    Args:
        u: Vector Function or UFL expression (three covariant components).
        v: Optional second one.
        mesh: The mesh, needed only if the expression does not reveal it.
        quadrature_degree: Fixed quadrature degree (``None``: UFL's estimate).

    Returns:
        ``{"l2": ..., "h1": ..., "vm": ...}``.
    """
    e = u if v is None else u - v
    kw: dict[str, Any] = {"mesh": mesh, "quadrature_degree": quadrature_degree}
    return {"l2": l2_norm(e, **kw), "h1": h1_norm(e, **kw), "vm": vm_norm(e, **kw)}


class DifferenceNorms:
    """``‖u − v‖`` in V_M (H¹×H¹×L²), full H¹ and L² for Functions of one space, compiled once."""

    def __init__(self, V: dolfinx.fem.FunctionSpace, quadrature_degree: int | None = None) -> None:
        self.e = dolfinx.fem.Function(V)
        mesh = V.mesh
        md = {} if quadrature_degree is None else {"quadrature_degree": quadrature_degree}
        dx = ufl.Measure("dx", domain=mesh, metadata=md)
        e = self.e
        values = [e[i] * e[i] for i in range(3)]
        grads = [ufl.inner(ufl.grad(e[i]), ufl.grad(e[i])) for i in range(3)]
        self.forms = {
            "l2": dolfinx.fem.form(sum(values) * dx),
            "h1": dolfinx.fem.form((sum(values) + sum(grads)) * dx),
            "vm": dolfinx.fem.form((sum(values) + grads[0] + grads[1]) * dx),
        }
        self.comm = mesh.comm

    def __call__(self, u: dolfinx.fem.Function, v: dolfinx.fem.Function | None = None) -> dict:
        """The three norms of ``u − v`` (of ``u`` if ``v`` is None)."""
        self.e.x.array[:] = u.x.array if v is None else u.x.array - v.x.array
        out = {}
        for name, form in self.forms.items():
            local = dolfinx.fem.assemble_scalar(form)
            out[name] = float(np.sqrt(max(self.comm.allreduce(local, op=MPI.SUM), 0.0)))
        return out
