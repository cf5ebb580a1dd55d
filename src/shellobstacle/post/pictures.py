"""The 3D picture of a solution: the deformed shell over the obstacle, coloured by the gap.

:func:`write_picture` gathers the deformed middle surface at the mesh vertices from every
rank onto rank 0 (:func:`gather_surface`) and has :mod:`shellobstacle.post.render3d` draw it
with PyVista in a process of its own (off screen: VTK's wheel uses an X display, EGL or
OSMesa, whichever the machine has). PyVista is the optional extra ``shellobstacle[pictures]``:
without it, or where no OpenGL context can be created, the first picture of a run returns a
warning naming the reason and the later ones are skipped silently; everything else a run
writes does not depend on it.

The renderer imports neither DOLFINx nor this package, so an obstacle other than the plane
``x·q = 0`` (a ball, a cylinder, a formula, a shifted plane) travels to it as
samples (:mod:`shellobstacle.post.obstacle_shape`): ``g`` on a grid of a box around the shell,
which it contours at 0, and the shell's vertices moved onto ``{g = 0}``, where it draws the
contact zone's outline.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import os
import re
import subprocess
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

import dolfinx
import dolfinx.fem
import numpy as np

from shellobstacle.geometry.surface import Surface
from shellobstacle.obstacle import Obstacle, Plane
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.obstacle_shape import level_box, onto
from shellobstacle.post.render3d import (
    CMAP,
    CONTACT,
    ELEVATIONS,
    EXIT_NO_PYVISTA,
    LINES,
    PLANE,
)

__all__ = [
    "Picture",
    "SurfaceData",
    "describe",
    "drawn_as_plane",
    "gather_surface",
    "obstacle_samples",
    "pictures_available",
    "write_picture",
]

#: seconds the drawing process may take before it is stopped (a picture is not worth more)
TIMEOUT = 600.0
_RENDERER = Path(__file__).with_name("render3d.py")
#: why pictures cannot be drawn in this process, once a picture has failed (None: not known)
_unavailable: str | None = None


@dataclass
class SurfaceData:
    """The deformed middle surface at the mesh vertices, in the global vertex order.

    Attributes:
        points: ``θ + U`` at the vertices, ``U = ζ_i a^i`` (shape ``(n, 3)``).
        reference: ``θ`` at the vertices.
        triangles: The cells as vertex triples (``(m, 3)``).
        gap: ``g(ζ)`` at the vertices (docs/model.md §3; for the plane ``(θ + U)·q``).
        contact: the contact indicator at the vertices (P1: 1 on contact vertices, else 0;
            :meth:`~shellobstacle.post.contact.Postprocessor.indicator`).
        q: Unit normal of the plane ``x·q = 0`` (for another obstacle, the pictures'
            vertical).
        level: For an obstacle other than the plane ``x·q = 0`` (:func:`drawn_as_plane`),
            ``g`` at the nodes of a grid of a box around the
            shell (shape ``(n1, n2, n3)``, :func:`~shellobstacle.post.obstacle_shape.level_box`);
            None for a plane.
        box: The grid's corner and spacing (shape ``(2, 3)``); None for a plane.
        onto: The points of ``{g = 0}`` nearest the vertices ``points`` (shape ``(n, 3)``,
            :func:`~shellobstacle.post.obstacle_shape.onto`); None for a plane.
        normal: The unit normals ``∇g/|∇g|`` there; None for a plane.
    """

    points: np.ndarray
    reference: np.ndarray
    triangles: np.ndarray
    gap: np.ndarray
    contact: np.ndarray
    q: np.ndarray
    level: np.ndarray | None = None
    box: np.ndarray | None = None
    onto: np.ndarray | None = None
    normal: np.ndarray | None = None

    def arrays(self) -> dict[str, np.ndarray]:
        """The fields that are set, by name (what :func:`shellobstacle.post.render3d.render`
        reads)."""
        fields = {name: getattr(self, name) for name in self.__dataclass_fields__}
        return {name: np.asarray(v) for name, v in fields.items() if v is not None}


def drawn_as_plane(obstacle: Obstacle) -> bool:
    """Whether the renderer draws ``obstacle`` as the plane ``x·q = 0`` (the paper's); any
    other obstacle, a shifted plane included, is drawn from its samples."""
    return isinstance(obstacle, Plane) and obstacle.level == 0.0


def describe(obstacle: Obstacle) -> str:
    """The obstacle in a picture's title: its own words
    (:meth:`~shellobstacle.obstacle.base.Obstacle.describe`), ``"the plane x·q = 0"``, ``"the
    ball of radius 2 centred at (0, 0, -2)"``, ..."""
    return obstacle.describe()


#: the box sampled around a curved obstacle: the shell's bounding box, widened on every side
#: by this fraction of its largest side and by the smallest gap (where the obstacle is nearest)
MARGIN = 0.3


def obstacle_samples(
    obstacle: Obstacle, surface: Surface, points: np.ndarray, gap: np.ndarray
) -> dict[str, np.ndarray]:
    """An obstacle's samples for the renderer: ``level``, ``box``, ``onto`` and
    ``normal`` of :class:`SurfaceData` for the deformed vertices ``points`` and their gaps."""
    G = surface.geometry_numpy(np.zeros((1, 2)))  # g lives in space: G names NumPy only
    lo, hi = points.min(axis=0), points.max(axis=0)
    pad = MARGIN * float(np.max(hi - lo)) + max(float(np.min(gap)), 0.0)
    origin, spacing, level = level_box(obstacle, G, lo - pad, hi + pad)
    on, normal = onto(obstacle, G, points)
    return {"level": level, "box": np.stack([origin, spacing]), "onto": on, "normal": normal}


@dataclass(frozen=True)
class Picture:
    """What :func:`write_picture` did: the file written, or why there is none.

    ``warning`` is set only for the first failure of a run (the later ones are silent).
    """

    path: Path | None
    warning: str | None = None


def _vertex_vectors(U: dolfinx.fem.Function, S: dolfinx.fem.FunctionSpace) -> np.ndarray:
    """The vector Function ``U`` at the dofs of the scalar P1 space ``S`` (local, with ghosts)."""
    V = U.function_space
    bs = V.dofmap.index_map_bs
    if V.element.basix_element.degree != 1:
        W = dolfinx.fem.functionspace(S.mesh, ("Lagrange", 1, (bs,)))
        vertex = dolfinx.fem.Function(W)
        vertex.interpolate(U)
        U, V = vertex, W
    values = U.x.array.reshape(-1, bs)
    # the same vertex is dof s of S and dof w of V in each cell: map S's dofs to V's
    w_of_s = np.empty(S.dofmap.index_map.size_local + S.dofmap.index_map.num_ghosts, np.int64)
    w_of_s[S.dofmap.list.ravel()] = V.dofmap.list.ravel()
    return values[w_of_s]


def gather_surface(post: Postprocessor, root: int = 0) -> SurfaceData | None:
    """The current solution's deformed surface (collective); ``root`` gets it, the others None.

    Every field is evaluated at the vertices (for P2 ``ζ``, its vertex values), on the owned
    vertices of each rank, and concatenated in rank order: that is the global numbering of
    the P1 dofs, which the owned cells' triangles are written in.
    """
    problem = post.problem
    comm = post.comm
    S = post.P1
    imap = S.dofmap.index_map
    n_owned = imap.size_local
    gap = post.nodal_gap().x.array
    contact = post.indicator().x.array
    U = _vertex_vectors(post.cartesian_displacement(), S)
    y = S.tabulate_dof_coordinates()[:n_owned]
    theta = np.column_stack(problem.shell.surface.theta_numpy(y)).astype(float)
    cells = problem.mesh.topology.index_map(problem.mesh.topology.dim).size_local
    local = S.dofmap.list[:cells]
    glob = imap.local_to_global(local.ravel().astype(np.int32)).reshape(-1, 3)
    parts = comm.gather(
        (theta, theta + U[:n_owned], gap[:n_owned].copy(), contact[:n_owned].copy(), glob),
        root=root,
    )
    if comm.rank != root:
        return None
    assert parts is not None
    data = SurfaceData(
        points=np.concatenate([p[1] for p in parts]),
        reference=np.concatenate([p[0] for p in parts]),
        triangles=np.concatenate([p[4] for p in parts]).astype(np.int64),
        gap=np.concatenate([p[2] for p in parts]),
        contact=np.concatenate([p[3] for p in parts]),
        q=np.asarray(problem.q, dtype=float),
    )
    if not drawn_as_plane(problem.obstacle):
        samples = obstacle_samples(problem.obstacle, problem.shell.surface, data.points, data.gap)
        data = dataclasses.replace(data, **samples)
    return data


def pictures_available() -> str | None:
    """None if PyVista is installed and no picture of this process has failed, else why not."""
    if _unavailable is not None:
        return _unavailable
    if importlib.util.find_spec("pyvista") is None:
        return "PyVista is not installed (pip install 'shellobstacle[pictures]')"
    return None


def _without_mpi(environ: Mapping[str, str]) -> dict[str, str]:
    """``environ`` without the variables by which an MPI launcher reaches its ranks: a VTK
    built with MPI must not join the solve's MPI job."""
    prefixes = ("PMI_", "PMIX_", "HYDRA_", "HYDI_", "MPIR_", "OMPI_", "MPICH_")
    return {k: v for k, v in environ.items() if not k.startswith(prefixes)}


def _plain(line: str) -> str:
    """A line of the renderer's stderr without colours and without VTK's log prefix."""
    line = re.sub(r"\x1b\[[0-9;]*m", "", line).strip()
    for level in ("WARN|", "ERR|"):
        if level in line:
            return line.split(level, 1)[1].strip()
    return line


def _draw(data: SurfaceData, path: Path, title: str) -> str | None:
    """Render ``data`` in a process of its own and lay the views out into ``path``; None on
    success, else why not."""
    arrays = path.with_name(f".{path.stem}.{os.getpid()}.surface.tmp")
    views = path.with_name(f".{path.stem}.{os.getpid()}.views.tmp")
    try:
        with arrays.open("wb") as f:
            np.savez(f, **data.arrays())
        run = subprocess.run(
            [sys.executable, "-P", str(_RENDERER), str(arrays), str(views)],
            capture_output=True,
            text=True,
            timeout=TIMEOUT,
            stdin=subprocess.DEVNULL,
            env=_without_mpi(os.environ),
        )
        if run.returncode == 0 and views.is_file():
            with np.load(views) as npz:
                _lay_out({k: npz[k] for k in npz.files}, path, title)
            return None
        lines = [_plain(line) for line in run.stderr.splitlines() if line.strip()]
        if run.returncode == EXIT_NO_PYVISTA:
            return lines[-1] if lines else "PyVista cannot be imported"
        how = f"signal {-run.returncode}" if run.returncode < 0 else f"status {run.returncode}"
        last = f": {lines[-1]}" if lines else ""
        return (
            f"the 3D drawing (PyVista/VTK off screen) ended with {how}{last}; VTK needs an X "
            "display, EGL or OSMesa (on Debian: apt-get install libegl1 libegl-mesa0 "
            "libgl1-mesa-dri, or libosmesa6)"
        )
    except subprocess.TimeoutExpired:
        return f"the 3D drawing took more than {TIMEOUT:g} s and was stopped"
    except OSError as err:
        return f"the 3D drawing could not run: {err}"
    finally:
        arrays.unlink(missing_ok=True)
        views.unlink(missing_ok=True)


def _from(elevation: float, curved: bool = False) -> str:
    """Where a view is seen from (over a curved obstacle: above the plane ``x·q = 0``, the
    horizontal)."""
    if elevation >= 90.0:
        return "from above"
    return f"{elevation:g}° above the horizontal" if curved else f"{elevation:g}° above the plane"


def _lay_out(views: dict[str, np.ndarray], path: Path, title: str) -> None:
    """The two views side by side with the gap's colour bar, a legend and ``title``."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from shellobstacle.post.plotting import plt, save_atomically

    clim = tuple(float(v) for v in views["clim"])
    curved = bool(views.get("curved", False))
    what = "the contact zone" if bool(views["contact"]) else "the lowest point (no contact vertex)"
    low, high = ELEVATIONS
    fig, axes = plt.subplots(1, 2, figsize=(13.0, 5.4), constrained_layout=True)
    for ax, image, label in (
        (axes[0], views["whole"], f"the whole shell, {_from(low, curved)}"),
        (axes[1], views["close"], f"{what}: the shell within {float(views['reach']):.3g} of "
         f"it, {_from(high)}"),
    ):  # fmt: skip
        ax.imshow(image)
        ax.set_axis_off()
        ax.set_title(label, fontsize=10)
    mappable = plt.cm.ScalarMappable(plt.Normalize(*clim), plt.get_cmap(CMAP))
    bar = fig.colorbar(mappable, ax=axes, shrink=0.8, pad=0.01)
    bar.set_label(
        "gap g(ζ) of the contact face (a ball's or a cylinder's: the distance to it)"
        if curved
        else "gap g(ζ) = (θ + ζᵢ aⁱ)·q, the height above the plane"
    )
    handles = [
        Line2D([], [], color=CONTACT, lw=3, label="contact zone: cells in contact at every vertex")
        if bool(views["outlined"])
        else Line2D([], [], color=CONTACT, ls="", marker="o", label="contact vertices"),
        Patch(
            facecolor=PLANE,
            label="the obstacle's surface g = 0 near the shell (translucent)"
            if curved
            else "the plane x·q = 0 (translucent)",
        ),
    ]
    if curved:
        handles.append(Line2D([], [], color=LINES, lw=1.5, label="lines of equal height x·q on it"))
    axes[1].legend(handles=handles, loc="lower left", fontsize=8, framealpha=0.9)
    where = "the obstacle" if curved else "the obstacle plane"
    fig.suptitle(title or f"Deformed middle surface θ + ζᵢ aⁱ over {where}")
    try:
        save_atomically(fig, path, dpi=110)
    finally:
        plt.close(fig)


def write_picture(post: Postprocessor, path: str | Path, title: str = "") -> Picture:
    """Draw the current solution of ``post.problem`` into the PNG ``path`` (collective).

    Rank 0 gathers the surface and draws it; the result is the same on every rank. Without
    PyVista, or when drawing fails, nothing is written: the first such call of the process
    returns the reason as :attr:`Picture.warning`, the later ones return no warning and do
    not try again.
    """
    comm: MPI.Comm = post.comm
    path = Path(path)
    why = comm.bcast(pictures_available() if comm.rank == 0 else None, root=0)
    if why is None:
        data = gather_surface(post)
        if comm.rank == 0:
            assert data is not None
            path.parent.mkdir(parents=True, exist_ok=True)
            why = _draw(data, path, title)
        why = comm.bcast(why, root=0)
        if why is None:
            return Picture(path)
    return _skipped(why)


def _skipped(why: str) -> Picture:
    """No picture: the reason as a warning the first time in this process, then silence."""
    global _unavailable
    if _unavailable is not None:
        return Picture(None)
    _unavailable = why
    return Picture(None, f"the 3D pictures are skipped: {why}")
