"""Test configuration: the DOLFINx wheel's environment is checked once, as the command does;
the paper's problem data and the meshes, solves and linear algebra shared by the tests
(imported as ``from conftest import ...``: a test module never imports another); hypothesis
made deterministic.

Hypothesis draws the same examples on every run (profile ``deterministic``, the default), so
that a random example can never fail CI by chance; ``HYPOTHESIS_PROFILE=random`` draws new
ones and ten times as many
(``HYPOTHESIS_PROFILE=random ./run test tests/config/test_config_fuzz.py``).
"""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from shellobstacle.compat import bootstrap
from shellobstacle.geometry.surface import Surface
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.spec import Discretization, Load, Material, Obstacle, Shell

bootstrap()

PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "deterministic")
settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("random", derandomize=False)
settings.load_profile(PROFILE)


def examples(n: int) -> int:
    """How many examples a property test with ``n`` draws: ten times as many when random."""
    return 10 * n if PROFILE == "random" else n


#: The paper's load of section 10 (docs/model.md): a pressure ∝ ε on the disk r < 0.06.
PAPER_LOAD = "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.06), (0, True))"
#: The paper's material: half-thickness ε and the Lamé constants λ, μ.
PAPER_MATERIAL = {"epsilon": 1e-3, "lam": 0.4, "mu": 0.012}


def make_paper_shell(
    load: str = PAPER_LOAD,
    model: str = "membrane",
    epsilon: float = PAPER_MATERIAL["epsilon"],
    parameters: dict[str, float] | None = None,
) -> Shell:
    """The paper's section 10 shell: the cap θ₃ = √(1 − |y|²) − 0.85, its material (at
    ``epsilon``) and ``(0, 0, load)``, under the plane x₃ = 0, with ``model``."""
    material = Material(epsilon, PAPER_MATERIAL["lam"], PAPER_MATERIAL["mu"])
    return Shell(
        Surface.spherical_cap(1.0, 0.85),
        material,
        Load(("0", "0", load), parameters or {}),
        Obstacle(),
        model,
    )


#: the paper's cap and material on a coarse disk: the head of a test's TOML config
CAP_ON_COARSE_DISK = """
[surface]
kind = "spherical_cap"
radius = 1.0
offset = 0.85

[domain]
kind = "disk"
radius = 0.5
h = 0.1

[material]
epsilon = 0.001
lambda = 0.4
mu = 0.012
"""

#: κ = h^1.5, the paper's coupling (docs/model.md §7)
PENALTY = PenaltySpec(exponent=1.5)


#: the constraint at the mesh's vertices (the nodal problem of the exact solvers)
VERTEX = Discretization(penalty_quadrature="vertex")
#: the relative KKT residuals an exact solver reaches (round-off)
KKT_TOL = 1e-10


def square(comm=None, n: int = 24, half: float = 0.25):
    """A structured mesh of ``[-half, half]²`` in ``n × n`` squares (the origin a vertex for
    even ``n``), on ``comm`` (MPI.COMM_WORLD if None), ghosted by one layer of cells across
    the ranks' facets (DOLFINx's default; Koiter's facet terms need both cells)."""
    from mpi4py import MPI

    import dolfinx

    comm = MPI.COMM_WORLD if comm is None else comm
    return dolfinx.mesh.create_rectangle(comm, [[-half, -half], [half, half]], [n, n])


def disk(refinements: int):
    """The paper's disk: gmsh's mesh at h = 0.08 refined uniformly ``refinements`` times."""
    from shellobstacle.mesh.domains import DomainSpec
    from shellobstacle.mesh.meshing import create_mesh

    return create_mesh(DomainSpec(kind="disk", radius=0.5, h=0.08, refinements=refinements))


def ladder(mesh) -> list[float]:
    """κ = h^0.5, h, h^1.5: the paper's continuation to κ = h^1.5 (:data:`PENALTY`'s)."""
    from shellobstacle.mesh.measures import mesh_size

    return PENALTY.ladder(mesh_size(mesh))


def cap_on_square(half: float, n: int, degree: int = 1, kappa: float = 1e-3):
    """The paper's shell on :func:`square` (``[-half, half]²``, ``n × n`` squares), compiled at
    ``κ``: the vertex penalty for P1, Gauss points for P2, quadrature degree 4 (the small
    problem of the output tests: ParaView files, 3D pictures)."""
    from shellobstacle.models.problem import PenalizedProblem

    quadrature = "vertex" if degree == 1 else "gauss"
    disc = Discretization(degree=degree, penalty_quadrature=quadrature, quadrature_degree=4)
    return PenalizedProblem(make_paper_shell(), square(n=n, half=half), disc, kappa=kappa)


def lu_solve(A, b):
    """``A⁻¹ b`` by MUMPS's LU: the reference of the tests of other linear solves."""
    from petsc4py import PETSc

    ksp = PETSc.KSP().create(A.getComm())
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    x = b.duplicate()
    ksp.solve(b, x)
    ksp.destroy()
    return x


def without_petsc_function(monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    """Make the symbol lookup of PETSc's C function ``name`` fail, as in a PETSc without it."""
    from shellobstacle.solvers import libpetsc

    lookup = libpetsc._lookup

    def failing(wanted: str):
        if wanted == name:
            raise AttributeError(f"undefined symbol: {name}")
        return lookup(wanted)

    monkeypatch.setattr(libpetsc, "_lookup", failing)


def ball(radius: float, side: str = "outside", **kw) -> Obstacle:
    """The ball whose top touches the plane x3 = 0 at the origin."""
    return Obstacle(kind="sphere", center=(0.0, 0.0, -radius), radius=radius, side=side, **kw)


def solve_on(
    obstacle: Obstacle,
    method: str = "newton",
    comm=None,
    penalty: PenaltySpec | None = PENALTY,
    discretization=None,
    n: int = 24,
    load: str | None = None,
):
    """The paper's shell over ``obstacle`` on :func:`square`, solved by ``method`` with
    ``penalty`` (None: the exact problem), asserted converged; returns the result and its
    contact figures."""
    import dataclasses

    from shellobstacle.api import solve_problem
    from shellobstacle.post.contact import Postprocessor

    shell = dataclasses.replace(make_paper_shell(*([load] if load else [])), obstacle=obstacle)
    r = solve_problem(shell, square(comm, n), penalty, discretization, method=method)
    assert r.converged, r.error
    return r, Postprocessor(r.problem, r.constraint).contact()


def owned_zeta(result):
    """The owned dofs of a result's ζ (a copy)."""
    V = result.problem.V
    return result.problem.zeta.x.array[: V.dofmap.index_map.size_local * 3].copy()


def global_max_abs(a) -> float:
    """``max |a|`` over every rank."""
    from mpi4py import MPI

    import numpy as np

    return MPI.COMM_WORLD.allreduce(float(np.max(np.abs(a), initial=0.0)), op=MPI.MAX)


def displace_through_plane(problem) -> None:
    """A smooth ζ, zero on :func:`square`'s boundary, that pushes the cap's top through the
    plane (ζ_3 = −0.2 at the centre)."""
    import numpy as np

    def zeta(x: np.ndarray) -> np.ndarray:
        b = (1 - 16 * x[0] ** 2) * (1 - 16 * x[1] ** 2)
        return np.stack([0.3 * x[0] * x[1] * b, -0.2 * x[0] ** 2 * b, (-0.2 + x[1]) * b])

    problem.zeta.interpolate(zeta)
    problem.zeta.x.scatter_forward()


@pytest.fixture
def shared_dir(tmp_path):
    """A folder that every MPI rank sees (rank 0's temporary folder)."""
    from cli_helpers import shared_folder

    yield from shared_folder(tmp_path)


#: test files that take half a minute or more of one core (measured from a clean clone),
#: started first so that pytest-xdist's workers finish together (a long file scheduled last
#: would run on its own at the end)
LONG_FIRST = (
    "test_docs.py",
    "test_nonlinear_koiter.py",
    "test_manufactured.py",
    "test_adapt_experiment.py",
    "test_cli_fuzz.py",
    "test_multigrid_ranks.py",
    "test_interrupt.py",
    "test_pictures.py",
    "test_jit_cache.py",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files of :data:`LONG_FIRST` first, in that order; the rest as collected."""
    rank = {name: k for k, name in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONG_FIRST)))
