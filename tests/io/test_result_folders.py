"""Result folders are consistent: a failed run never blocks its rerun, ``--overwrite`` replaces a
folder whole or not at all, ``log.txt`` says how a run ended, a saved ``config.toml`` reruns from
anywhere, default names say what ran, unusable output paths are user errors.

Runs use ``examples/small.toml`` at h = 0.1 (a second each). The replacement tests are marked
``mpi``: under ``mpiexec -n 2`` every rank writes into the staging folder (ParaView output is
collective) and rank 0 swaps it in.
"""

from __future__ import annotations

import os
import shutil
import tomllib
from pathlib import Path

from mpi4py import MPI

import pytest
from cli_helpers import run_on_all_ranks as run

from shellobstacle.cli.main import EXIT_INTERRUPTED, main
from shellobstacle.solvers.newton.solver import NewtonSolver

ROOT = Path(__file__).parents[2]
SMALL = str(ROOT / "examples" / "small.toml")
COMM = MPI.COMM_WORLD
serial = pytest.mark.skipif(COMM.size > 1, reason="runs serially")

SOLVE = ["solve", SMALL, "-q", "--set", "domain.h=0.1", "--set", "output.figures=false"]
NO_PARAVIEW = ["--set", "output.paraview=false"]
#: the folders, not the 3D pictures (tests/post/test_pictures.py), are under test here
NO_PICTURES = ["--set", "output.pictures=false"]
#: the shell through the plane: the assumptions fail after the folder is prepared
THROUGH_PLANE = ["--set", "surface.offset=1.2"]
SWEEP = ["experiment", "penalty", SMALL, "-q", "--set", "domain.h=0.1"]
PENALTY = [*SWEEP, *NO_PICTURES, "--quadratures", "vertex", "--q-max", "2"]


def interrupt_solve(monkeypatch: pytest.MonkeyPatch, at: int) -> None:
    """Raise KeyboardInterrupt (as Ctrl-C does) at Newton solve number ``at``, on every rank."""
    solve, calls = NewtonSolver.solve, [0]

    def counted(solver, *args, **kwargs):
        calls[0] += 1
        if calls[0] == at:
            raise KeyboardInterrupt
        return solve(solver, *args, **kwargs)

    monkeypatch.setattr(NewtonSolver, "solve", counted)


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# --------------------------------------------------------------------------- failed runs, rerun


@serial
def test_a_solve_that_fails_before_results_does_not_block_its_rerun(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """The failed run leaves its log (with the error) in -o OUT; the fixed rerun proceeds and
    leaves nothing of it."""
    out = tmp_path / "out"
    assert main([*SOLVE, *THROUGH_PLANE, "-o", str(out)]) == 2
    assert names(out) == ["config.toml", "log.txt"]
    assert "error: the data break the theory's assumptions" in (out / "log.txt").read_text()
    assert "offset = 1.2" in (out / "config.toml").read_text()
    capsys.readouterr()
    assert main([*SOLVE, *NO_PARAVIEW, "-o", str(out)]) == 0
    assert "summary.json" in names(out)
    assert "error" not in (out / "log.txt").read_text()
    assert "offset = 0.85" in (out / "config.toml").read_text()


@serial
def test_an_experiment_with_a_bad_option_creates_no_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """Options are checked before the folder is made: exit 2, one line, nothing written."""
    monkeypatch.chdir(tmp_path)
    assert main([*SWEEP, "--quadratures", "gaus"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("shellobstacle: error: --quadratures: 'gaus' is not one of 'gauss'")
    assert len(err.strip().splitlines()) == 1
    assert names(tmp_path) == []


@serial
def test_an_experiment_interrupted_before_its_first_step_does_not_block_its_rerun(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """steps/ with only meta.json and a mesh fingerprint holds no results: the rerun of the same
    command proceeds (no --resume, no --overwrite)."""
    out = tmp_path / "b1"
    with monkeypatch.context() as m:
        interrupt_solve(m, at=1)
        assert main([*PENALTY, "-o", str(out)]) == EXIT_INTERRUPTED
    assert names(out / "steps") == ["batch1_mesh0_h0.1_vertex_mesh.json", "meta.json"]
    assert main([*PENALTY, "-o", str(out)]) == 0
    assert (out / "report.md").is_file()
    assert "--- resumed ---" not in (out / "log.txt").read_text()


@serial
def test_an_interrupted_sweep_with_finished_steps_is_kept_for_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """Finished steps are results: a plain rerun is refused (naming --resume), --resume goes on."""
    out = tmp_path / "b1"
    with monkeypatch.context() as m:
        interrupt_solve(m, at=3)
        assert main([*PENALTY, "-o", str(out)]) == EXIT_INTERRUPTED
    records = names(out / "steps")
    assert "batch1_mesh0_h0.1_vertex_q0.5.json" in records
    capsys.readouterr()
    assert main([*PENALTY, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds the finished steps of an interrupted run" in err
    assert f"--resume -o {out}" in err and "--overwrite" in err
    assert names(out / "steps") == records
    assert main([*PENALTY, "-o", str(out), "--resume"]) == 0
    assert (out / "report.md").is_file()


# --------------------------------------------------------------------------- --overwrite


@pytest.mark.mpi
def test_a_failing_overwrite_keeps_the_old_results(shared_dir: Path) -> None:
    """A user error, a bug and an interruption during --overwrite: OUT is byte for byte the old
    folder; the failed run's log is in .OUT.partial, which the next run removes."""
    out = shared_dir / "out"
    assert run([*SOLVE, "-o", str(out)]) == 0
    if COMM.rank == 0:
        (out / "notes.txt").write_text("planted")
    COMM.barrier()
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    partial = shared_dir / ".out.partial"

    assert run([*SOLVE, *THROUGH_PLANE, "-o", str(out), "--overwrite"]) == 2
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert "the data break the theory's assumptions" in (partial / "log.txt").read_text()

    import shellobstacle.io.paraview

    real = shellobstacle.io.paraview.write_paraview

    def broken(*args, **kwargs):
        real(*args, **kwargs)  # collective: every rank writes its part into the staging folder
        raise RuntimeError("simulated bug after the ParaView output")

    with pytest.MonkeyPatch.context() as m:
        m.setattr(shellobstacle.io.paraview, "write_paraview", broken)
        assert run([*SOLVE, "-o", str(out), "--overwrite"]) == 1
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert (partial / "surface.bp").is_dir()
    assert "simulated bug after the ParaView output" in (partial / "log.txt").read_text()

    with pytest.MonkeyPatch.context() as m:
        interrupt_solve(m, at=2)
        assert run([*SOLVE, "-o", str(out), "--overwrite"]) == EXIT_INTERRUPTED
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert "interrupted" in (partial / "log.txt").read_text()
    assert not (shared_dir / ".out.old").exists()


@pytest.mark.mpi
def test_a_successful_overwrite_replaces_the_folder_whole(shared_dir: Path) -> None:
    """Nothing of the old run survives (a planted file, its ParaView output, a staging folder
    left by a failed run); the new results are complete, ParaView files of every rank
    included."""
    out = shared_dir / "out"
    assert run([*SOLVE, "-o", str(out)]) == 0
    old_summary = (out / "summary.json").read_bytes()
    if COMM.rank == 0:
        (out / "stale.txt").write_text("from the old run")
        (shared_dir / ".out.partial").mkdir()
        (shared_dir / ".out.partial" / "log.txt").write_text("a failed run")
    COMM.barrier()
    assert run([*SOLVE, *NO_PARAVIEW, "--set", "domain.h=0.08", "-o", str(out), "--overwrite"]) == 0
    assert names(out) == ["checks.txt", "config.toml", "log.txt", "summary.json"]
    assert (out / "summary.json").read_bytes() != old_summary
    assert tomllib.loads((out / "config.toml").read_text())["domain"]["h"] == 0.08
    assert names(shared_dir) == ["out"]
    assert run([*SOLVE, "-o", str(out), "--overwrite"]) == 0
    assert (out / "surface.bp").is_dir() and (out / "summary.json").is_file()
    assert "replaced" in (out / "log.txt").read_text()
    assert names(shared_dir) == ["out"]


@serial
def test_a_solve_that_does_not_converge_replaces_the_old_results(tmp_path: Path) -> None:
    """Its last iterate and residual history are a complete record of the run (exit 1)."""
    out = tmp_path / "out"
    assert main([*SOLVE, *NO_PARAVIEW, "-o", str(out)]) == 0
    args = [*SOLVE, *NO_PARAVIEW, "--set", "solver.max_iterations=1"]
    args += ["--set", "penalty.continuation=false", "-o", str(out), "--overwrite"]
    assert main(args) == 1
    assert '"converged": false' in (out / "summary.json").read_text()
    assert names(tmp_path) == ["out"]


@serial
def test_an_interrupted_overwrite_of_a_sweep_resumes_beside_the_old_results(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture
) -> None:
    """The finished steps of an interrupted --overwrite are in .OUT.partial: a plain rerun is
    refused, --resume -o OUT continues them and swaps the finished folder in."""
    out = tmp_path / "b1"
    assert main([*PENALTY, "-o", str(out)]) == 0
    report = (out / "report.md").read_bytes()
    with monkeypatch.context() as m:
        interrupt_solve(m, at=3)
        assert main([*PENALTY, "-o", str(out), "--overwrite"]) == EXIT_INTERRUPTED
    err = capsys.readouterr().err
    assert f"--resume -o {out}" in err and ".b1.partial/steps/" in err
    assert (out / "report.md").read_bytes() == report
    assert main([*PENALTY, "-o", str(out)]) == 2
    assert "holds the finished steps of an interrupted run replacing" in capsys.readouterr().err
    assert main([*PENALTY, "-o", str(out), "--resume"]) == 0
    assert names(tmp_path) == ["b1"]
    assert "resumed: 2 finished step(s)" in (out / "log.txt").read_text()


# --------------------------------------------------------------------------- the log


@serial
def test_the_error_that_ended_a_run_is_in_its_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A user error, a solver failure, a bug (with its traceback) and an interruption."""
    assert main([*SOLVE, *THROUGH_PLANE, "-o", str(tmp_path / "user")]) == 2
    log = (tmp_path / "user" / "log.txt").read_text()
    assert "error: the data break the theory's assumptions: inside half-space" in log

    args = [*SOLVE, *NO_PARAVIEW, "--set", "solver.max_iterations=1"]
    assert main([*args, "--set", "penalty.continuation=false", "-o", str(tmp_path / "a")]) == 1
    assert "FAILED: Newton did not converge" in (tmp_path / "a" / "log.txt").read_text()

    import shellobstacle.io.summary

    def broken(*_args, **_kwargs):
        raise RuntimeError("simulated bug in write_solution")

    with monkeypatch.context() as m:
        m.setattr(shellobstacle.io.summary, "write_solution", broken)
        assert main([*SOLVE, "-o", str(tmp_path / "bug")]) == 1
    log = (tmp_path / "bug" / "log.txt").read_text()
    assert "internal error (a bug):" in log and "Traceback (most recent call last)" in log
    assert "RuntimeError: simulated bug in write_solution" in log

    with monkeypatch.context() as m:
        interrupt_solve(m, at=1)
        assert main([*SOLVE, "-o", str(tmp_path / "stop")]) == EXIT_INTERRUPTED
    assert (tmp_path / "stop" / "log.txt").read_text().splitlines()[-1].endswith("interrupted")


# --------------------------------------------------------------------------- config, names, paths


def _write_disk_msh(path: Path) -> None:
    """gmsh: the disk of radius 0.5 with mesh size 0.1."""
    import gmsh

    gmsh.initialize(readConfigFiles=False, interruptible=False)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.1)
    gmsh.model.add("disk")
    gmsh.model.occ.addDisk(0, 0, 0, 0.5, 0.5)
    gmsh.model.occ.synchronize()
    gmsh.model.mesh.generate(2)
    gmsh.write(str(path))
    gmsh.finalize()


@serial
def test_a_saved_config_reruns_from_anywhere(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file domain's mesh path, relative to the config, is saved absolute: the saved
    config.toml, copied to another folder, reruns (from yet another working folder)."""
    project = tmp_path / "project"
    project.mkdir()
    _write_disk_msh(project / "disk.msh")
    config = project / "c.toml"
    text = Path(SMALL).read_text().replace('kind = "disk"', 'kind = "file"\npath = "disk.msh"')
    config.write_text(text.replace("h = 0.04", ""))
    first = tmp_path / "first"
    assert main(["solve", str(config), "-q", *NO_PARAVIEW, *NO_PICTURES, "-o", str(first)]) == 0
    saved = tomllib.loads((first / "config.toml").read_text())
    assert saved["domain"]["path"] == str(project / "disk.msh")
    elsewhere, cwd = tmp_path / "elsewhere", tmp_path / "cwd"
    elsewhere.mkdir()
    cwd.mkdir()
    shutil.copy(first / "config.toml", elsewhere / "again.toml")
    monkeypatch.chdir(cwd)
    assert main(["solve", str(elsewhere / "again.toml"), "-q", *NO_PARAVIEW]) == 0
    again = tomllib.loads((cwd / "again-solve" / "config.toml").read_text())
    assert again == saved
    assert (cwd / "again-solve" / "summary.json").read_text() != ""


@serial
def test_default_folder_names_say_what_ran(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """solve → CONFIG-solve, -2, ...; experiment → CONFIG-BATCH; reproduce → reproduce-MODE."""
    monkeypatch.chdir(tmp_path)
    assert main([*SOLVE, *NO_PARAVIEW]) == 0
    assert main([*SOLVE, *NO_PARAVIEW]) == 0
    assert main(PENALTY) == 0
    import shellobstacle.experiments.reproduce as reproduce

    def quick(folder: Path, mode: str, *_args: object) -> Path:
        (folder / "report.md").write_text(f"# {mode}\n")
        return folder / "report.md"

    monkeypatch.setattr(reproduce, "reproduce", quick)
    assert main(["reproduce", "-q"]) == 0
    assert names(tmp_path) == ["reproduce-fast", "small-penalty", "small-solve", "small-solve-2"]
    assert (tmp_path / "small-solve-2" / "summary.json").is_file()
    assert (tmp_path / "small-penalty" / "report.md").is_file()
    assert (tmp_path / "reproduce-fast" / "report.md").read_text() == "# fast\n"


def _one_line_error(err: str, *needles: str) -> None:
    assert "Traceback" not in err, err
    assert err.startswith("shellobstacle: error: ") and len(err.strip().splitlines()) == 1, err
    for needle in needles:
        assert needle in err, err


@serial
def test_unusable_output_paths_are_user_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """An existing file, a folder below a file, a read-only folder, a folder of other files:
    exit 2 and one line naming the path and the fix."""
    afile = tmp_path / "afile"
    afile.write_text("mine")
    assert main([*SOLVE, "-o", str(afile)]) == 2
    _one_line_error(capsys.readouterr().err, f"'{afile}' is a file", "choose another -o")
    assert main([*SOLVE, "-o", str(afile / "sub" / "out")]) == 2
    _one_line_error(capsys.readouterr().err, f"'{afile}' is a file", "choose another -o")
    assert afile.read_text() == "mine"

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "config.toml").write_text("my own config")
    assert main([*SOLVE, "-o", str(mine), "--overwrite"]) == 2
    _one_line_error(capsys.readouterr().err, str(mine), "not results of shellobstacle")
    assert (mine / "config.toml").read_text() == "my own config"

    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o555)
        assert main([*SOLVE, "-o", str(locked / "out")]) == 2
        _one_line_error(capsys.readouterr().err, f"'{locked}' is not writable")


@serial
def test_a_failed_swap_leaves_the_old_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """If the new folder cannot be renamed into place, the old one is put back; a swap cut short
    between its two renames is repaired by the next run (the old folder comes back)."""
    from shellobstacle.io import folders
    from shellobstacle.io.folders import ResultsError, prepare_folder
    from shellobstacle.io.lock import release_folders

    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("old")
    where = prepare_folder(out, "unused", overwrite=True)
    assert where.path == tmp_path / ".out.partial" and where.target == out
    (where.path / "summary.json").write_text("new")
    replace = os.replace

    def failing(src, dst):
        if Path(src) == where.path:
            raise PermissionError(13, "Permission denied")
        replace(src, dst)

    with monkeypatch.context() as m:
        m.setattr(folders.os, "replace", failing)
        with pytest.raises(ResultsError, match=r"'.*out' is unchanged, the new results are in"):
            where.commit()
    assert names(tmp_path) == [".out.lock", ".out.partial", "out"]  # (held by this run)
    assert (out / "summary.json").read_text() == "old"
    where.commit()
    assert names(tmp_path) == [".out.lock", "out"] and (out / "summary.json").read_text() == "new"

    out.rename(tmp_path / ".out.old")  # as if cut short between the renames
    with pytest.raises(ResultsError, match="already holds results"):
        prepare_folder(out, "unused", overwrite=False)
    release_folders()
    assert names(tmp_path) == ["out"] and (out / "summary.json").read_text() == "new"
