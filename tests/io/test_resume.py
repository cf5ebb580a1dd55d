"""Interrupted sweeps continue with ``--resume`` without recomputing finished steps (issue:
reliable under bad input and faults); ``-v`` prints the Newton iterations."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

from mpi4py import MPI

import numpy as np
import pytest
from cli_helpers import run_on_all_ranks as run

from shellobstacle.cli.main import EXIT_INTERRUPTED, main
from shellobstacle.io.checkpoint import Checkpoint
from shellobstacle.solvers.newton.solver import NewtonSolver

ROOT = Path(__file__).parents[2]
PAPER = str(ROOT / "examples" / "paper.toml")
PARABOLOID = str(ROOT / "examples" / "paraboloid.toml")
COMM = MPI.COMM_WORLD
serial = pytest.mark.skipif(COMM.size > 1, reason="runs serially (the mpi variant is below)")

PENALTY = ["experiment", "penalty", PAPER, "--set", "domain.h=0.06", "--quadratures", "vertex"]
MESH = ["experiment", "mesh", PAPER, "--set", "domain.h=0.15", "--refinements", "2"]
MESH += ["--q", "0.5,1.0"]
LOAD = ["experiment", "load", PARABOLOID, "--set", "domain.h=0.06", "--values", "0,40,80"]
# what is resumed is the tables and the solutions: no 3D picture (tests/post/test_pictures.py)
for _sweep in (PENALTY, MESH, LOAD):
    _sweep += ["--set", "output.pictures=false"]


class Solves:
    """Counts ``NewtonSolver.solve`` calls; raises KeyboardInterrupt on call ``stop``.

    ``recorded`` holds the call count at each step record written (``Checkpoint.save``).
    """

    def __init__(self, monkeypatch: pytest.MonkeyPatch, stop: int | None = None) -> None:
        self.calls, self.stop, self.recorded = 0, stop, []
        solve, save = NewtonSolver.solve, Checkpoint.save

        def counted(solver, *args, **kwargs):
            self.calls += 1
            if self.calls == self.stop:
                raise KeyboardInterrupt
            return solve(solver, *args, **kwargs)

        def saved(cp, key, record):
            save(cp, key, record)
            if cp.enabled:
                self.recorded.append(self.calls)

        monkeypatch.setattr(NewtonSolver, "solve", counted)
        monkeypatch.setattr(Checkpoint, "save", saved)


NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|nan|inf")


def assert_same_numbers(a: str, b: str, what: str, abs_tol: float = 1e-20) -> None:
    """The texts agree, numbers to 1e-12 relative (values below ``abs_tol`` are round-off)."""
    ta, tb = NUMBER.split(a), NUMBER.split(b)
    assert ta == tb, f"{what}: the texts differ"
    for x, y in zip(NUMBER.findall(a), NUMBER.findall(b), strict=True):
        fx, fy = float(x), float(y)
        assert math.isclose(fx, fy, rel_tol=1e-12, abs_tol=abs_tol), f"{what}: {x} != {y}"


def without_times(report: str) -> str:
    """The report without the `seconds` table columns and the note on resumed steps."""
    out, drop = [], None
    for line in report.splitlines():
        if line.startswith("Resumed:"):
            continue
        if line.startswith("|"):
            cells = line.strip("|").split("|")
            if drop is None and any(c.strip() == "seconds" for c in cells):
                drop = [i for i, c in enumerate(cells) if c.strip() == "seconds"]
            if drop is not None and not set(line) <= set("|-"):
                cells = [c for i, c in enumerate(cells) if i not in drop]
            line = "|".join(cells)
        else:
            drop = None
        out.append(line)
    return "\n".join(out).strip()


def without_seconds(record):
    """A JSON record without its timings and round-off-level residuals.

    The relative residual at convergence is round-off (1e-15) and, under MPI, not bitwise
    reproducible from run to run (parallel reductions), so it is left out.
    """
    if isinstance(record, dict):
        return {
            k: without_seconds(v)
            for k, v in record.items()
            if "seconds" not in k and k != "relative_residual"
        }
    if isinstance(record, list):
        return [without_seconds(v) for v in record]
    return record


def assert_same_results(a: Path, b: Path, abs_tol: float = 1e-20) -> None:
    """CSV tables, report and step records agree (numbers to 1e-12 relative, times aside)."""
    csvs = sorted(p.name for p in a.glob("*.csv"))
    assert csvs and csvs == sorted(p.name for p in b.glob("*.csv"))
    for name in csvs:
        assert_same_numbers((a / name).read_text(), (b / name).read_text(), name, abs_tol)
    ra, rb = (without_times((p / "report.md").read_text()) for p in (a, b))
    assert_same_numbers(ra.replace(str(a), "OUT"), rb.replace(str(b), "OUT"), "report.md", abs_tol)
    records = sorted(p.name for p in (a / "steps").glob("*.json") if p.name != "meta.json")
    assert records == sorted(p.name for p in (b / "steps").glob("*.json") if p.name != "meta.json")
    for name in records:
        ja, jb = (json.loads((p / "steps" / name).read_text()) for p in (a, b))
        assert_same_numbers(
            json.dumps(without_seconds(ja)), json.dumps(without_seconds(jb)), name, abs_tol
        )


def interrupted_then_resumed(
    monkeypatch: pytest.MonkeyPatch,
    folder: Path,
    args: list[str],
    stop: int,
    abs_tol: float = 1e-20,
) -> None:
    """Run ``args`` uninterrupted, then interrupted at solve ``stop`` and resumed; compare."""
    with monkeypatch.context() as m:
        full = Solves(m)
        assert run([*args, "-q", "-o", str(folder / "full")]) == 0
    with monkeypatch.context() as m:
        first = Solves(m, stop=stop)
        out = folder / "resumed"
        assert run([*args, "-q", "-o", str(out)]) == EXIT_INTERRUPTED
        assert first.recorded, "no step finished before the interruption"
        assert not (out / "report.md").exists()
    with monkeypatch.context() as m:
        second = Solves(m)
        assert run([*args, "-q", "-o", str(out), "--resume"]) == 0
    finished = first.recorded[-1]  # solves spent on the recorded steps
    assert 0 < finished < full.calls
    assert second.calls == full.calls - finished, "finished steps were solved again"
    assert "--- resumed ---" in (out / "log.txt").read_text()
    assert not list((out / "steps").glob("*.npy")), "vectors are kept after the run finished"
    assert_same_results(folder / "full", out, abs_tol)


@serial
def test_penalty_sweep_resumes_without_recomputing(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Batch 1 interrupted at its 4th κ continues from the 3rd and ends as if uninterrupted."""
    interrupted_then_resumed(monkeypatch, tmp_path, PENALTY, stop=4)
    assert "(recorded)" in (tmp_path / "resumed" / "log.txt").read_text()


@serial
def test_mesh_sweep_resumes_without_recomputing(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Batch 2 interrupted in its second q: warm starts and level differences are restored."""
    interrupted_then_resumed(monkeypatch, tmp_path, MESH, stop=5)


@serial
def test_load_sweep_resumes_without_recomputing(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Batch 3 (a load sweep) interrupted at its last value continues from the recorded one."""
    interrupted_then_resumed(monkeypatch, tmp_path, LOAD, stop=5)


@pytest.mark.mpi
def test_penalty_sweep_resumes_under_mpi(monkeypatch: pytest.MonkeyPatch, shared_dir: Path) -> None:
    """The same as the serial penalty test on every rank (resume with the same ranks)."""
    # Two uninterrupted 2-rank runs already differ in the last digits (parallel reductions in
    # a different order); the recorded numbers are norms of differences of solutions of size
    # ~1e-2, so their round-off is absolute, ~1e-16·‖ζ‖ times the conditioning: compare them
    # to 1e-15 absolute (a resume bug changes them by far more).
    interrupted_then_resumed(
        monkeypatch, shared_dir, PENALTY, stop=3, abs_tol=1e-15 if COMM.size > 1 else 1e-20
    )


@serial
def test_resume_refuses_a_different_run(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """--resume on a folder of another config or sweep names the difference (exit 2)."""
    out = str(tmp_path / "b1")
    with monkeypatch.context() as m:
        Solves(m, stop=2)
        assert main([*PENALTY, "-q", "-o", out]) == EXIT_INTERRUPTED
    assert "--resume -o" in capsys.readouterr().err
    assert main([*PENALTY, "-q", "-o", out, "--resume", "--set", "domain.h=0.07"]) == 2
    err = capsys.readouterr().err
    assert "cannot resume" in err and "config.domain.h: 0.06" in err and "0.07 now" in err
    args = [*PENALTY, "-q", "-o", out, "--resume", "--tol", "1e-5"]
    assert main(args) == 2
    assert "--tol" in capsys.readouterr().err
    assert main([*MESH, "-q", "-o", out, "--resume"]) == 2
    assert "batch: 'penalty' in the interrupted run, 'mesh' now" in capsys.readouterr().err


@serial
def test_resume_refuses_a_different_mesh(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """A saved solution whose nodes are not the mesh's is refused, not silently used."""
    out = tmp_path / "b1"
    with monkeypatch.context() as m:
        Solves(m, stop=3)
        assert main([*PENALTY, "-q", "-o", str(out)]) == EXIT_INTERRUPTED
    saved = sorted((out / "steps").glob("*.npy"))
    # the solution of the last finished step and the solver's contact zone with it
    assert [p.name.endswith(".zone.npy") for p in saved] == [False, True]
    vector = saved[0]
    data = np.load(vector)
    data[0, 0] += 1e-4
    np.save(vector, data)
    assert main([*PENALTY, "-q", "-o", str(out), "--resume"]) == 2
    assert "the mesh differs from the interrupted run's: cannot resume" in capsys.readouterr().err


@serial
def test_resume_needs_the_folder_of_an_interrupted_run(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """--resume without -o, or on a folder without steps/, is a user error (exit 2)."""
    assert main([*PENALTY, "-q", "--resume"]) == 2
    assert "--resume needs -o OUT" in capsys.readouterr().err
    other = tmp_path / "other"
    other.mkdir()
    (other / "summary.json").write_text("{}")
    assert main([*PENALTY, "-q", "--resume", "-o", str(other)]) == 2
    assert "no steps/meta.json" in capsys.readouterr().err
    assert main(["reproduce", "-q", "--resume", "-o", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert (other / "summary.json").read_text() == "{}"
    with pytest.raises(SystemExit) as info:
        main([*PENALTY, "--resume", "--overwrite", "-o", str(other)])
    assert info.value.code == 2


@serial
def test_verbose_prints_newton_iterations(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """-v adds a line per Newton iteration and the step lengths; -q prints nothing."""
    args = ["solve", str(ROOT / "examples" / "small.toml"), "--set", "domain.h=0.1"]
    args += ["--set", "output.paraview=false", "--set", "output.figures=false"]
    assert main([*args, "-v", "-o", str(tmp_path / "v")]) == 0
    err = capsys.readouterr().err
    assert re.search(r"Newton 1: relative residual \d\.\d+e[-+]\d+", err)
    assert "step lengths" in err
    assert "Newton 1: relative residual" in (tmp_path / "v" / "log.txt").read_text()
    assert main([*args, "-q", "-o", str(tmp_path / "q")]) == 0
    assert capsys.readouterr().err == ""
    with pytest.raises(SystemExit):
        main([*args, "-q", "-v"])


@serial
def test_a_picture_not_drawn_before_the_interruption_is_said_missing(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """Ctrl-C while the largest load's solution is drawn, after its step was recorded: the
    resumed run reads that solution back and does not draw it, and says so in report.md and
    on stderr (not a report without its picture and without a word)."""
    import shellobstacle.post.pictures

    args = ["experiment", "load", PARABOLOID, "--set", "domain.h=0.06", "--values", "0,40,80"]
    out = tmp_path / "load"

    def interrupted(*_args, **_kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(shellobstacle.post.pictures, "write_picture", interrupted)
        assert main([*args, "-q", "-o", str(out)]) == EXIT_INTERRUPTED
    capsys.readouterr()
    assert main([*args, "-o", str(out), "--resume"]) == 0
    err = capsys.readouterr().err
    report = (out / "report.md").read_text()
    assert not (out / "batch3_shell_3d.png").exists()
    missing = "3D picture (the shell in 3D at ell = 80) is missing"
    assert f"*The {missing}: this run read its solution back" in report
    assert err.count(f"warning: the {missing}") == 1, err
    assert f"warning: the {missing}" in (out / "log.txt").read_text()
