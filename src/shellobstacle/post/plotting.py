"""Matplotlib figures (Agg backend, PNG): cross-sections of the deformed shell (docs/model.md §7).

Only rank 0 draws: pass the same data on every rank (as
:func:`~shellobstacle.post.sections.cross_section` returns it) and call from all ranks.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

from mpi4py import MPI

import matplotlib.pyplot as plt
import numpy as np

from shellobstacle.post.sections import CrossSection, horizontal_direction

__all__ = ["plot_cross_section", "save_atomically"]


def _curved(sections) -> bool:
    """Whether the sections come with a curved obstacle's profile (else the plane's)."""
    return sections[0][1].obstacle_height is not None


def _heights(sec: CrossSection, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertical coordinates of the reference and deformed curves: the gaps ``g`` over a
    plane, the heights ``x·q`` over a curved obstacle."""
    if sec.obstacle_height is None:
        return sec.height_reference, sec.height_deformed
    return sec.reference @ q, sec.deformed @ q


def _draw(ax, sections, t, ref_label: bool) -> None:
    """Obstacle, reference shell and deformed curves on one axes: over a plane the gaps ``g``
    (the plane at 0), over a curved obstacle its profile (thick grey, hatched below) and the
    heights ``x·q`` (:func:`_heights`)."""
    first = sections[0][1]
    q = np.asarray(first.q, float)
    if _curved(sections):
        s, z = first.obstacle_s, first.obstacle_height
        label = "obstacle g = 0" if ref_label else None
        ax.plot(s, z, color="0.45", lw=3.0, zorder=1, label=label)
        ax.fill_between(
            s, z, -1e3, facecolor="0.92", edgecolor="0.6", hatch="///", lw=0.0, zorder=0
        )
    else:
        ax.axhline(0.0, color="0.45", lw=3.0, zorder=1)
        ax.axhspan(-1e3, 0.0, facecolor="0.92", edgecolor="0.6", hatch="///", lw=0.0, zorder=0)
    ax.plot(
        first.reference @ t,
        _heights(first, q)[0],
        ls="--",
        color="0.25",
        lw=1.2,
        label="reference shell θ" if ref_label else None,
        zorder=2,
    )
    colors = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, max(len(sections), 1)))
    for (label, sec), color in zip(sections, colors, strict=False):
        ax.plot(sec.deformed @ t, _heights(sec, q)[1], color=color, lw=1.6, label=label, zorder=3)


def plot_cross_section(
    sections: Sequence[tuple[str, CrossSection]],
    q: Sequence[float],
    path: str | Path,
    *,
    title: str | None = None,
    zoom: float | None = 0.15,
    comm: MPI.Comm = MPI.COMM_WORLD,
) -> Path:
    """Plot cross-sections of the deformed shell ``θ + ζ_i a^i`` over the obstacle.

    The horizontal axis is the coordinate of the deformed point along the direction of the
    plane closest to the sampling axis (``x_1`` for ``q = (0, 0, 1)`` and a section along
    ``y1``). Over the plane ``x·q = 0`` the vertical axis is the gap ``g``, the height above
    the plane, and the plane is the thick grey line at 0 (hatched below). Over a curved
    obstacle (the sections carry its profile, :class:`CrossSection`) the vertical axis is the
    height ``x·q`` and the obstacle is its profile in the section's vertical plane: the height
    of its upper surface under each horizontal position, a curve read against the shell's
    without converting gaps (a gap is a distance along ``∇g``, not a height). The reference
    shell θ is dashed (drawn from the first section), and each section is one curve. A second
    panel zooms onto ``|x_1| < zoom`` near the contact zone.

    Args:
        sections: ``(label, section)`` pairs, e.g. one per load level ℓ.
        q: Unit normal of the plane.
        path: PNG file to write (150 dpi).
        title: Figure title (a default one otherwise).
        zoom: Half-width of the zoom panel; ``None`` for a single panel.
        comm: Communicator whose rank 0 draws.

    Returns:
        The path (the file is written by rank 0 only; call it from every rank).
    """
    path = Path(path)
    if not sections:
        raise ValueError("plot_cross_section needs at least one (label, section) pair")
    if comm.rank != 0:
        return path
    first = sections[0][1]
    t = horizontal_direction(q, first.axis)
    other = "y2" if first.axis == "y1" else "y1"
    xlabel = "horizontal position x₁" if np.allclose(t, [1, 0, 0]) else "horizontal position x·t"
    if np.allclose(t, [0, 1, 0]):
        xlabel = "horizontal position x₂"

    panels = 2 if zoom else 1
    fig, axes = plt.subplots(
        1, panels, figsize=(6.4 * panels, 4.6), squeeze=False, constrained_layout=True
    )
    ax = axes[0, 0]
    _draw(ax, sections, t, True)
    curved = _curved(sections)
    ylabel = "height x·q" if curved else "height above the plane x·q"
    if curved:
        q_ = np.asarray(first.q, float)
        heights = [h for _, s in sections for h in _heights(s, q_)]
        floor = first.obstacle_height[
            (first.obstacle_s >= float((first.deformed @ t).min()))
            & (first.obstacle_s <= float((first.deformed @ t).max()))
        ]
        high = max(float(np.nanmax(h)) for h in heights)
        low = min(float(np.nanmin(h)) for h in [*heights, floor] if np.isfinite(h).any())
        span = max(high - low, 1e-12)
        ax.set_ylim(low - 0.08 * span, high + 0.12 * span)
    else:
        top = max(float(np.nanmax(s.height_reference)) for _, s in sections)
        bottom = min(0.0, *(float(np.nanmin(s.height_deformed)) for _, s in sections))
        ax.set_ylim(bottom - 0.08 * top, 1.12 * top)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ats = {(sec.axis, sec.at) for _, sec in sections}
    ax.set_title(f"section {other} = {first.at:g}" if len(ats) == 1 else "sections")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8, framealpha=0.9)

    if zoom:
        zax = axes[0, 1]
        _draw(zax, sections, t, False)
        if curved:
            q_ = np.asarray(first.q, float)
            near = [_heights(s, q_)[1][np.abs(s.deformed @ t) < zoom] for _, s in sections]
            under = first.obstacle_height[np.abs(first.obstacle_s) < zoom]
            near = [h for h in near if h.size]
            hmax = max((float(h.max()) for h in near), default=high)
            hmin = min((float(h.min()) for h in near), default=low)
            if np.isfinite(under).any():
                hmin = min(hmin, float(np.nanmin(under)))
            span = max(hmax - hmin, 1e-12)
            zax.set_ylim(hmin - 0.1 * span, hmax + 0.1 * span)
        else:
            near = [s.height_deformed[np.abs(s.deformed @ t) < zoom] for _, s in sections]
            near = [h for h in near if h.size]
            hmax = max((float(h.max()) for h in near), default=top)
            hmin = min((float(h.min()) for h in near), default=0.0)
            span = max(hmax - min(hmin, 0.0), 1e-12)
            zax.set_ylim(min(hmin, 0.0) - 0.1 * span, hmax + 0.1 * span)
        zax.set_xlim(-zoom, zoom)
        zax.set_xlabel(xlabel)
        zax.set_ylabel(ylabel)
        zax.set_title(f"zoom |{xlabel.split()[-1]}| < {zoom:g}: contact zone")
        zax.grid(alpha=0.3)

    default = "over the obstacle g = 0" if curved else "over the obstacle plane"
    fig.suptitle(title or f"Deformed middle surface θ + ζᵢ aⁱ {default}")
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        save_atomically(fig, path, dpi=150)
    finally:
        plt.close(fig)
    return path


def save_atomically(fig, path: Path, **kwargs) -> None:
    """``fig.savefig(path)`` through a temporary file in the same folder and ``os.replace``.

    The format comes from the suffix of ``path``, as for ``savefig`` (PNG if it has none);
    readers never see a partly written file, and a failed save leaves ``path`` untouched.
    """
    fmt = path.suffix[1:].lower() or "png"
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fig.savefig(tmp, format=fmt, **kwargs)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
