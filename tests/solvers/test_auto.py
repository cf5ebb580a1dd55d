"""``"auto"`` resolved once per solve, from the problem alone (solvers/auto.py): the machine's
memory only refuses what would not fit, naming the fix; summary.json records each choice and
why."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

from mpi4py import MPI

import pytest
from cli_helpers import SMALL, run, serial
from conftest import PENALTY, ball, disk, make_paper_shell

from shellobstacle import api
from shellobstacle.mesh import memory, resources
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.solvers import auto
from shellobstacle.solvers.auto import estimated_linear_solver, takes_linear_solver
from shellobstacle.solvers.newton import solver as newton_solver
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.registry import METHODS

GIB = 2.0**30
#: the paper's disk at h = 0.003: about 0.30 M dofs, 1.3 GiB for the direct path and 0.9 GiB
#: for multigrid (mesh/memory.py), below the 1 M dofs from which "auto" takes multigrid
MEDIUM = DomainSpec("disk", 0.003, radius=0.5)


def machine(monkeypatch: pytest.MonkeyPatch, gib: float) -> None:
    """Make this machine's memory ``gib`` GiB."""
    monkeypatch.setattr(memory, "machine_memory", lambda: gib * GIB)


@pytest.mark.mpi
def test_auto_resolves_alike_whatever_the_machines_memory(monkeypatch) -> None:
    """The paper's problem on a refined disk takes the same linear solver, nested iteration
    and reasons on a machine of 1 MiB as on one of 1 TiB (the direct path: below 1 M dofs);
    the memory is read only by the refusal before meshing, which a ready mesh skips."""
    mesh = disk(1)
    choices = []
    for gib in (2.0**-10, 2.0**10):
        machine(monkeypatch, gib)
        result = api.solve_problem(make_paper_shell(), mesh, PENALTY)
        assert result.converged, result.error
        choices.append((result.extra["linear_solver"], result.extra["choices"]))
    assert choices[0] == choices[1]
    assert choices[0][0] == "direct"
    assert choices[0][1]["linear_solver"]["reason"] == "below 1 M dofs the direct path is as fast"


def test_the_memory_decides_the_refusal_not_the_choice(monkeypatch) -> None:
    """About 0.30 M dofs: "auto" is the direct path on a machine of 1.5 GiB as on one of
    64 GiB; the small machine refuses it before meshing, naming multigrid (which fits) and
    the other fixes in one line; the large one lets it through."""
    newton = METHODS["newton"]
    for gib in (1.5, 64.0):
        machine(monkeypatch, gib)
        assert estimated_linear_solver(newton, None, MEDIUM, "membrane", 1) == "direct"
    machine(monkeypatch, 1.5)
    with pytest.raises(resources.ResourceError) as refused:
        api.solve_problem(make_paper_shell(), MEDIUM, PENALTY)
    message = str(refused.value)
    assert "more than 80% of its 1.5 GiB: use a larger h" in message, message
    assert 'solver.linear_solver = "multigrid" (about 0.899 GiB)' in message, message
    assert "or pass --force" in message and "\n" not in message
    machine(monkeypatch, 64.0)
    assert resources.require_fits(MEDIUM, linear_solver="direct") is not None


def test_a_solve_resolves_auto_once(monkeypatch) -> None:
    """A solve over a ball (several passes of the linearized gap, each a solve of the
    method) with multigrid on a refined disk resolves its options once: nested iteration
    "auto" is on serially (off on several ranks), and the passes take it as resolved."""
    calls: list[object] = []
    resolve = auto.resolve

    def counted(problem, options):
        calls.append(options)
        return resolve(problem, options)

    for module in (auto, api, newton_solver):
        monkeypatch.setattr(module, "resolve", counted)
    shell = dataclasses.replace(make_paper_shell(), obstacle=ball(2.0))
    options = NewtonOptions(linear_solver="multigrid")
    result = api.solve_problem(shell, disk(1), PENALTY, options=options)
    assert result.converged, result.error
    assert result.extra["linearizations"] > 1
    assert len(calls) == 1
    nested = "on" if MPI.COMM_WORLD.size == 1 else "off"
    assert result.extra["choices"]["nested_iteration"]["chosen"] == nested
    assert ("nested_iteration" in result.extra) is (nested == "on")


@serial
def test_the_summary_records_each_choice_and_why(capsys, tmp_path: Path) -> None:
    """summary.json's ``choices``: per option that may say "auto", what was asked, what was
    chosen and why; a value asked for by name is recorded as asked for."""
    out = tmp_path / "run"
    sets = ["domain.h=0.1", "domain.refinements=1", "solver.nested_iteration=off"]
    sets += ["output.pictures=false", "output.paraview=false"]
    code, _, err = run(capsys, "solve", str(SMALL), "-o", str(out), *(f"--set={s}" for s in sets))
    assert code == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["choices"] == {
        "linear_solver": {
            "asked": "auto",
            "chosen": "direct",
            "reason": "below 1 M dofs the direct path is as fast",
        },
        "nested_iteration": {"asked": "off", "chosen": "off", "reason": "asked for"},
    }
    assert summary["linear_solver"] == "direct"


def test_the_estimate_asks_the_method_whether_it_takes_a_linear_solver() -> None:
    """A method takes a linear solver when its options declare ``linear_solver`` (whatever
    its name); the others are estimated as a factorization."""

    @dataclass(frozen=True)
    class Options:
        linear_solver: str = "multigrid"

    @dataclass
    class Throwaway:
        name: str = "throwaway"
        options_type: type = Options

    assert takes_linear_solver(Throwaway()) and takes_linear_solver(METHODS["newton"])
    assert not takes_linear_solver(METHODS["brezis-sibony"])
    assert not takes_linear_solver(METHODS["active-set"])
    assert estimated_linear_solver(Throwaway(), None, MEDIUM, "membrane", 1) == "multigrid"
    multigrid = NewtonOptions(linear_solver="multigrid")
    assert estimated_linear_solver(METHODS["snes-vi"], multigrid, MEDIUM, "membrane", 1) == (
        "direct"
    )
