"""Draw the deformed shell over the obstacle in 3D with PyVista, off screen.

This module runs in a process of its own (``python render3d.py SURFACE.npz VIEWS.npz``, started
by :func:`shellobstacle.post.pictures.write_picture`, which lays the views out with their
colour bar and legend): it imports only NumPy and PyVista, not MPI, DOLFINx or the rest of the
package. An OpenGL context that cannot be created (no X display, no EGL, no OSMesa) makes VTK
end its process with a segmentation fault instead of an exception, and a process of its own
keeps the solve that called it alive.

The views show the deformed middle surface ``θ + ζ_i a^i`` coloured by the gap
``g(ζ) = (θ + ζ_i a^i)·q`` (docs/model.md §3), the plane ``x·q = 0`` as a translucent grey square
(the penalized solution's slight penetration, ``g < 0``, shows through it) and the boundary of
the contact zone as a red tube: of the cells whose vertices all touch (contact indicator > ½,
:meth:`~shellobstacle.post.contact.Postprocessor.indicator`), the flat
part of the shell on the plane, which the steep wall around it does not hide from above.

Any obstacle but the plane ``x·q = 0`` comes as samples (``level``, ``box``, ``onto``, ``normal``:
:class:`shellobstacle.post.pictures.SurfaceData`): its surface is the contour ``g = 0`` of the
sampled grid, translucent grey as the plane and cut to the plane's square seen along ``q``, with
darker lines of equal height ``x·q`` on it (a ball's are circles: its curvature shows); the
outline lies on it, on the vertices' nearest points of ``{g = 0}`` (``onto``), lifted along
the normal by the tube's radius.

Exit status: 0 written, 3 PyVista (or VTK) cannot be imported, anything else a failure
(message on stderr).
"""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence

import numpy as np

__all__ = ["EXIT_NO_PYVISTA", "contact_mark", "main", "obstacle_surface", "plane_frame", "render"]

EXIT_NO_PYVISTA = 3
#: the size in pixels of each 3D view, and the camera's elevations above the plane (degrees)
WINDOW = (1000, 800)
ELEVATIONS = (15.0, 90.0)
CMAP = "viridis"
PLANE = "#b0b0b0"
LINES = "#707070"
CONTACT = "#e31a1c"


def plane_frame(q: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An orthonormal frame ``(t1, t2, q)`` of space with ``t1``, ``t2`` in the plane ``x·q = 0``.

    ``t1`` is the direction of the plane closest to ``x_1`` (to ``x_2`` if ``q`` is along
    ``x_1``), so that for ``q = (0, 0, 1)`` the frame is the Cartesian one.
    """
    n = np.asarray(q, dtype=float)
    n = n / np.linalg.norm(n)
    axis = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t1 = axis - (axis @ n) * n
    t1 /= np.linalg.norm(t1)
    return t1, np.cross(n, t1), n


def obstacle_surface(data: Mapping[str, np.ndarray]):
    """The contour ``g = 0`` of a curved obstacle's samples (``level`` on the grid ``box``), a
    PyVista surface (with point normals, for smooth shading; empty if ``g`` keeps one sign)."""
    import pyvista as pv

    level = np.asarray(data["level"], dtype=float)
    origin, spacing = np.asarray(data["box"], dtype=float)
    grid = pv.ImageData(dimensions=level.shape, spacing=tuple(spacing), origin=tuple(origin))
    grid.point_data["g"] = level.ravel(order="F")  # VTK's order: the first index fastest
    surface = grid.contour([0.0], scalars="g", method="flying_edges")
    if not surface.n_cells:  # the obstacle does not cross the box
        return surface
    return surface.compute_normals(consistent_normals=True)  # for smooth shading


def _cut(surface, frame, mid: np.ndarray, half: float):
    """The part of ``surface`` over the square of half-side ``half`` centred at ``mid`` (its
    coordinates along ``t1``, ``t2``), seen along ``q``: the plane's square."""
    t1, t2, _ = frame
    points = np.asarray(surface.points)
    surface = surface.copy()
    surface.point_data["reach"] = np.maximum(
        np.abs(points @ t1 - mid[0]), np.abs(points @ t2 - mid[1])
    )
    return surface.clip_scalar("reach", invert=True, value=half)


def _height_lines(surface, q: np.ndarray, count: int = 9):
    """``count`` lines of constant height ``x·q`` on ``surface``, evenly spaced inside its
    range of heights (a ball's are circles: they show its curvature through the grey); none
    on a surface of one height (a plane normal to ``q``: its heights differ by the contour's
    single-precision round-off only)."""
    import pyvista as pv

    points = np.asarray(surface.points)
    heights = points @ q
    if np.ptp(heights) <= 1e-4 * float(np.ptp(points, axis=0).max()):
        return pv.PolyData()
    surface = surface.copy()
    surface.point_data["height"] = heights
    levels = np.linspace(heights.min(), heights.max(), count + 2)[1:-1]
    return surface.contour(list(levels), scalars="height")


def contact_mark(data: Mapping[str, np.ndarray], triangles: np.ndarray, q, radius: float):
    """The contact zone's mark among the cells ``triangles``, lifted by ``radius`` to lie on the
    obstacle, not in it: onto the plane ``x·q = 0`` along ``q``, or, for a curved obstacle, to
    the vertices' points of ``{g = 0}`` (``onto``) along its normal.

    Returns:
        The boundary of the cells that touch at every vertex (a PyVista PolyData of lines); if
        no cell does, the contact vertices (an array ``(k, 3)``); None without contact.
    """
    import pyvista as pv

    points = np.asarray(data["points"], dtype=float)
    touching = np.asarray(data["contact"], dtype=float)[triangles] > 0.5
    if not touching.any():
        return None
    curved = "level" in data
    zone = pv.PolyData(points, np.hstack([np.full((len(triangles), 1), 3), triangles]))
    if curved:
        zone.point_data["vertex"] = np.arange(len(points))
    zone = zone.extract_cells(np.flatnonzero(touching.all(axis=1)))
    outline = zone.extract_feature_edges(
        boundary_edges=True, feature_edges=False, manifold_edges=False,
        non_manifold_edges=False,
    )  # fmt: skip
    if outline.n_points:
        if curved:
            vertex = np.asarray(outline.point_data["vertex"])
            outline.points = data["onto"][vertex] + radius * data["normal"][vertex]
        else:
            outline.points += np.outer(radius - outline.points @ q, q)
        return outline
    touched = np.unique(triangles[touching])
    if curved:
        return data["onto"][touched] + radius * data["normal"][touched]
    spots = points[touched]
    spots += np.outer(radius - spots @ q, q)
    return spots


def _view(data, frame, patch, elevation: float, clim, window) -> np.ndarray:
    """One off-screen view of the obstacle, the deformed shell (its cells with a vertex in
    ``patch``, a boolean mask of the vertices) and the contact zone's boundary, with the
    camera ``elevation`` degrees above the plane; an RGB image."""
    import pyvista as pv

    t1, t2, q = frame
    points = np.asarray(data["points"], dtype=float)
    triangles = np.asarray(data["triangles"], dtype=np.int64)
    triangles = triangles[patch[triangles].any(axis=1)]
    contact = np.asarray(data["contact"], dtype=float)
    faces = np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel()
    shell = pv.PolyData(points, faces)
    shell.point_data["gap"] = np.asarray(data["gap"], dtype=float)
    shell.point_data["contact"] = contact
    shell = shell.clean()  # drop the vertices of no cell

    along = np.column_stack([shell.points @ t1, shell.points @ t2])
    lo, hi = along.min(axis=0), along.max(axis=0)
    width = float(max(hi - lo))
    mid = (lo + hi) / 2
    plane = pv.Plane(
        center=mid[0] * t1 + mid[1] * t2, direction=q, i_size=1.5 * width, j_size=1.5 * width
    )
    pl = pv.Plotter(off_screen=True, window_size=list(window))
    pl.set_background("white")
    curved = "level" in data
    if curved:
        obstacle = data["obstacle"]
        if obstacle.n_cells:
            obstacle = _cut(obstacle, frame, mid, 0.75 * width)
        if obstacle.n_cells:
            pl.add_mesh(obstacle, color=PLANE, opacity=0.55, smooth_shading=True)
            lines = _height_lines(obstacle, q)
            if lines.n_points:
                pl.add_mesh(lines, color=LINES, line_width=1.5, opacity=0.8)
    else:
        # translucent: the shell's penetration of the plane (the penalty's g < 0) stays visible
        pl.add_mesh(plane, color=PLANE, opacity=0.55)
    pl.add_mesh(
        shell, scalars="gap", cmap=CMAP, clim=clim, smooth_shading=True, show_scalar_bar=False
    )
    mark = contact_mark(data, triangles, q, 0.008 * width)
    if isinstance(mark, np.ndarray):  # no cell touches with all its vertices: the vertices
        pl.add_mesh(pv.PolyData(mark), color=CONTACT, point_size=14,
                    render_points_as_spheres=True)  # fmt: skip
    elif mark is not None:
        pl.add_mesh(mark.tube(radius=0.008 * width), color=CONTACT)
    el, az = np.radians(elevation), np.radians(-60.0)
    direction = np.cos(el) * (np.cos(az) * t1 + np.sin(az) * t2) + np.sin(el) * q
    focus = shell.points.mean(axis=0)
    pl.camera.focal_point = tuple(focus)
    pl.camera.position = tuple(focus + 4.0 * width * direction)
    pl.camera.up = tuple(q if elevation < 80.0 else t2)  # from above: x1 to the right
    pl.reset_camera()
    image = pl.screenshot(None, return_img=True)
    pl.close()
    return _crop(image)


def _crop(image: np.ndarray, pad: int = 8) -> np.ndarray:
    """``image`` without its white margins (``pad`` pixels of them kept)."""
    drawn = np.argwhere((image[..., :3] < 250).any(axis=-1))
    if not len(drawn):
        return image
    (r0, c0), (r1, c1) = drawn.min(axis=0), drawn.max(axis=0)
    return image[max(r0 - pad, 0) : r1 + pad + 1, max(c0 - pad, 0) : c1 + pad + 1]


def render(data: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The two views of the module docstring as RGB images.

    The whole shell from 15° above the plane (low enough that its rise shows), and the part of
    the shell around the contact zone from straight above (the zone lies at the bottom of a
    dimple, hidden from low views); with no contact, around the lowest vertex instead.

    Args:
        data: ``points`` (deformed nodes ``θ + U``, shape ``(n, 3)``), ``triangles``
            (``(m, 3)`` node indices), ``gap`` and ``contact`` (``(n,)``, the indicator 1 on
            contact nodes) and ``q`` (the plane's unit normal); for a curved obstacle also
            ``level``, ``box``, ``onto`` and ``normal`` (the module docstring).

    Returns:
        ``whole`` and ``close`` (images, ``(rows, columns, 3)`` bytes), ``clim`` (the range of
        the colour scale: ``min(g, 0)``, ``max g``), ``reach`` (the close view shows the
        shell within this distance of the zone's centre along the plane), ``contact``
        (whether a vertex touches), ``outlined`` (whether a cell touches with all its
        vertices: the zone is outlined; else its vertices are marked) and ``curved`` (whether
        the obstacle drawn is a curved one's contour).
    """
    frame = plane_frame(data["q"])
    t1, t2, _ = frame
    if "level" in data:  # contoured once, cut to each view's square
        data = {**data, "obstacle": obstacle_surface(data)}
    points = np.asarray(data["points"], dtype=float)
    gap = np.asarray(data["gap"], dtype=float)
    contact = np.asarray(data["contact"], dtype=float) > 0.5
    clim = (float(min(gap.min(), 0.0)), float(max(gap.max(), 1e-300)))
    along = np.column_stack([points @ t1, points @ t2])
    extent = float(max(along.max(axis=0) - along.min(axis=0)))
    whole = _view(data, frame, np.ones(len(points), bool), ELEVATIONS[0], clim, WINDOW)
    near = along[contact] if contact.any() else along[[int(np.argmin(gap))]]
    center = near.mean(axis=0)
    reach = max(2.5 * float(np.linalg.norm(near - center, axis=1).max()), 0.12 * extent)
    patch = np.linalg.norm(along - center, axis=1) <= reach
    close = _view(data, frame, patch, ELEVATIONS[1], clim, WINDOW)
    return {
        "whole": whole,
        "close": close,
        "clim": np.array(clim),
        "reach": np.array(reach),
        "contact": np.array(contact.any()),
        "outlined": np.array(contact[np.asarray(data["triangles"])].all(axis=1).any()),
        "curved": np.array("level" in data),
    }


def main(argv: Sequence[str] | None = None) -> int:
    """``render3d.py SURFACE.npz VIEWS.npz``: :func:`render` in its own process."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 2:
        print("usage: render3d.py SURFACE.npz VIEWS.npz", file=sys.stderr)
        return 2
    try:
        import pyvista  # noqa: F401
    except ImportError as err:
        print(f"PyVista cannot be imported: {err}", file=sys.stderr)
        return EXIT_NO_PYVISTA
    with np.load(args[0]) as npz:
        data = {k: npz[k] for k in npz.files}
    views = render(data)
    with open(args[1], "wb") as f:
        np.savez(f, **views)
    return 0


if __name__ == "__main__":
    sys.exit(main())
