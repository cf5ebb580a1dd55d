"""The FFCx JIT cache stays sound when runs are interrupted (shellobstacle.cli.jit_cache), with real
processes on a throwaway cache (``XDG_CACHE_HOME`` of each test: the shared ``~/.cache`` is
never touched).

FFCx's protocol: the process that creates ``NAME.c`` compiles and then creates ``NAME.c.cached``;
the others wait for it. A source left without its marker makes the next compilation wait and
time out; a marker without its source makes every later one fail with ``FileExistsError``.
"""

from __future__ import annotations

import importlib.machinery
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from mpi4py import MPI

import pytest

from shellobstacle.cli import jit_cache

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="runs its own processes")

ROOT = Path(__file__).parents[2]
SMALL = str(ROOT / "examples" / "small.toml")

#: compiles the form x^K v dx (K = argv[1]); argv[2] pauses it: "after" CFFI has built the
#: module until the file argv[3] exists, "during" the build until interrupted; "wait" prints
#: FFCx's messages while it waits for another process's compilation; the last argument "guard":
#: inside jit_cache.guarded_compilations
COMPILE = textwrap.dedent(
    """
    import contextlib, os, sys, time
    import cffi
    from mpi4py import MPI
    import dolfinx, ufl
    from shellobstacle.cli.jit_cache import guarded_compilations

    k, pause = int(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else ""
    build = cffi.FFI.compile

    def paused(self, *args, **kwargs):
        if pause == "during":
            os.write(1, b"compiling\\n")  # (FFCx redirects sys.stdout meanwhile)
            time.sleep(600)
        built = build(self, *args, **kwargs)
        if pause == "after":
            os.write(1, b"compiled\\n")
            while not os.path.exists(sys.argv[3]):
                time.sleep(0.05)
        return built

    cffi.FFI.compile = paused
    if pause == "wait":  # (FFCx sets its logger's level from its options)
        import ffcx.codegeneration.jit

        ffcx.codegeneration.jit.logger.info = lambda m: os.write(1, m.encode() + b"\\n")
    mesh = dolfinx.mesh.create_unit_interval(MPI.COMM_SELF, 2)
    v = ufl.TestFunction(dolfinx.fem.functionspace(mesh, ("Lagrange", 1)))
    x = ufl.SpatialCoordinate(mesh)
    guard = guarded_compilations() if sys.argv[-1] == "guard" else contextlib.nullcontext()
    with guard:
        dolfinx.fem.form(x[0] ** k * v * ufl.dx)
    print("done", flush=True)
    """
)


@pytest.fixture
def env(tmp_path: Path) -> dict[str, str]:
    """The environment of a process using the throwaway cache ``tmp_path/cache/fenics``."""
    return {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "cache"), "PYTHONUNBUFFERED": "1"}


def cache(env: dict[str, str]) -> Path:
    return Path(env["XDG_CACHE_HOME"]) / "fenics"


def start(env: dict[str, str], *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def wait_for(proc: subprocess.Popen, line: str, stream: str = "stdout") -> None:
    """Read ``proc``'s ``stream`` up to ``line``; fail if it ends first."""
    for got in getattr(proc, stream):
        if got.strip().endswith(line):
            return
    pytest.fail(f"no '{line}': {proc.wait()} {proc.stdout.read()} {proc.stderr.read()}")


def compile_form(env: dict[str, str], k: int) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", COMPILE, str(k)], env=env, capture_output=True, text=True
    )


def unfinished(env: dict[str, str]) -> list[jit_cache.BrokenEntry]:
    """Every source without its marker, whatever its age, and every other broken entry."""
    return jit_cache.broken_entries(cache(env), now=math.inf)


def test_an_interrupted_run_leaves_another_process_s_compilation_alone(
    tmp_path: Path, env: dict[str, str]
) -> None:
    """A solve is interrupted while another process has built a form's module but not yet
    written its marker; that process finishes, and a third compiles the form again. (The solve
    runs for a minute at h = 0.01: it is still running when interrupted a few seconds in.)"""
    out = tmp_path / "out"
    run = start(
        env, "-m", "shellobstacle", "solve", SMALL, "--set", "domain.h=0.01", "-o", str(out)
    )
    go = tmp_path / "go"
    other = None
    try:
        wait_for(run, f"results go to {out}/", "stderr")
        other = start(env, "-c", COMPILE, "3", "after", str(go))
        wait_for(other, "compiled")
        run.send_signal(signal.SIGINT)
        _, err = run.communicate(timeout=120)
        assert run.returncode == 130, err
        assert err.strip().endswith("shellobstacle: interrupted"), err
        go.touch()
        _, err = other.communicate(timeout=120)
        assert other.returncode == 0, err
    finally:  # no process of this test outlives it
        for proc in (run, other):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
    assert unfinished(env) == []  # the interrupted run's own source is gone too
    third = compile_form(env, 3)
    assert third.returncode == 0, third.stderr


def test_a_process_interrupted_while_it_waits_for_the_same_form_leaves_it_alone(
    tmp_path: Path, env: dict[str, str]
) -> None:
    """Two processes compile the same new form: the first builds it, the second (guarded, as
    every command is) waits for it and is interrupted. The first then finishes, the entry is
    whole (its source, marker and module), and a third process loads it."""
    go = tmp_path / "go"
    first = start(env, "-c", COMPILE, "7", "after", str(go), "guard")
    wait_for(first, "compiled")
    (source,) = cache(env).glob("*.c")
    second = start(env, "-c", COMPILE, "7", "wait", "-", "guard")
    wait_for(second, f"Waiting for {source}.cached to appear.")
    second.send_signal(signal.SIGINT)
    _, err = second.communicate(timeout=120)
    assert "KeyboardInterrupt" in err and second.returncode != 0, err
    assert source.exists()  # the waiting process did not take it for its own
    go.touch()
    out, err = first.communicate(timeout=120)
    assert first.returncode == 0 and out.strip().endswith("done"), err
    assert source.exists() and source.with_suffix(".c.cached").exists()
    assert unfinished(env) == []
    third = compile_form(env, 7)
    assert third.returncode == 0 and third.stdout.strip() == "done", third.stderr
    assert list(cache(env).glob("*.c")) == [source]  # loaded, not compiled again


def test_an_interrupted_compilation_removes_its_own_source(env: dict[str, str]) -> None:
    """Without the guard the source stays and the next compilation fails after FFCx's timeout;
    with it, the next compilation proceeds."""
    for guard, k in (("", 4), ("guard", 5)):
        proc = start(env, "-c", COMPILE, str(k), "during", "-", guard)
        wait_for(proc, "compiling")
        (source,) = cache(env).glob("*.c")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
        assert "KeyboardInterrupt" in err
        if guard:
            assert not source.exists() and unfinished(env) == []
            again = compile_form(env, k)
            assert again.returncode == 0, again.stderr
        else:
            assert [e.source for e in unfinished(env)] == [source]
            again = compile_form(env, k)
            assert "TimeoutError" in again.stderr, again.stderr
            source.unlink()


def doctor(env: dict[str, str], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "shellobstacle", "doctor", *args],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_doctor_finds_and_repairs_a_poisoned_entry(env: dict[str, str]) -> None:
    """A source removed under a finished entry (what a clean-up of another process's files did):
    every compilation of the form fails until ``doctor --repair``."""
    assert compile_form(env, 6).returncode == 0
    (source,) = cache(env).glob("*.c")
    source.unlink()
    failed = compile_form(env, 6)
    assert "FileExistsError" in failed.stderr, failed.stderr
    found = doctor(env)
    assert found.returncode == 1
    assert f"{source.name}: marker without its source" in found.stdout
    assert "shellobstacle doctor --repair" in found.stdout
    repaired = doctor(env, "--repair")
    assert f"repaired the FFCx cache: removed {source}.cached" in repaired.stdout
    assert "FFCx cache" not in repaired.stdout.split("repaired the FFCx cache")[-1]
    again = compile_form(env, 6)
    assert again.returncode == 0, again.stderr


def test_broken_entries_by_hand(tmp_path: Path) -> None:
    """Each broken state is found, and repaired by removing only the files at fault; a finished
    entry, a fresh compilation and a module without marker or source are left alone."""
    so = importlib.machinery.EXTENSION_SUFFIXES[0]
    files = {
        "no_source": [".c.cached", ".c.failed", so],
        "no_module": [".c", ".c.cached"],
        "killed": [".c", so],
        "compiling": [".c"],
        "finished": [".c", ".c.cached", so, ".o"],
        "leftover": [so, ".o"],
    }
    for name, suffixes in files.items():
        for suffix in suffixes:
            (tmp_path / f"libffcx_forms_{name}{suffix}").write_text("")
    old = 1000.0
    os.utime(tmp_path / "libffcx_forms_killed.c", (old, old))
    found = jit_cache.broken_entries(tmp_path, now=old + jit_cache.UNFINISHED_AGE + 1)
    assert [(e.source.name, e.why) for e in found] == [
        ("libffcx_forms_killed.c", jit_cache.UNFINISHED),
        ("libffcx_forms_no_module.c", jit_cache.NO_MODULE),
        ("libffcx_forms_no_source.c", jit_cache.NO_SOURCE),
    ]
    removed = {p.name for p in jit_cache.repair(found)}
    assert removed == {
        "libffcx_forms_killed.c",
        "libffcx_forms_no_module.c",
        "libffcx_forms_no_module.c.cached",
        "libffcx_forms_no_source.c.cached",
    }
    assert jit_cache.broken_entries(tmp_path, now=math.inf) == [
        jit_cache.BrokenEntry(tmp_path / "libffcx_forms_compiling.c", jit_cache.UNFINISHED)
    ]


def test_a_cached_form_is_found_by_its_file_name(tmp_path, monkeypatch) -> None:
    """FFCx 0.11 lists the whole cache folder to load a cached form (a cost growing with every
    form ever compiled); with :func:`~shellobstacle.compat.locate_jit_modules_by_path` a form
    compiled once is loaded again without any listing, and a new form still compiles."""
    import ffcx.codegeneration.jit as jit
    import ufl
    from dolfinx import fem, mesh

    from shellobstacle.compat import locate_jit_modules_by_path

    assert locate_jit_modules_by_path() and locate_jit_modules_by_path()  # FFCx 0.11, once
    domain = mesh.create_unit_square(MPI.COMM_SELF, 2, 2)
    V = fem.functionspace(domain, ("Lagrange", 1))
    x = ufl.SpatialCoordinate(domain)
    forms = [x[0] ** k * ufl.TestFunction(V) * ufl.dx for k in (3, 4)]
    options = {"cache_dir": str(tmp_path)}
    fem.form(forms[0], jit_options=options)  # compiled into the empty folder

    listings = []
    find_spec = importlib.machinery.FileFinder.find_spec

    def listing(finder, name, target=None):
        if Path(finder.path) == tmp_path:
            listings.append(name)
        return find_spec(finder, name, target)

    monkeypatch.setattr(importlib.machinery.FileFinder, "find_spec", listing)
    fem.form(forms[0], jit_options=options)
    assert listings == []
    fem.form(forms[1], jit_options=options)  # not cached yet: FFCx's own way
    assert len(list(tmp_path.glob("*.c.cached"))) == 2
    monkeypatch.setattr(jit, "get_cached_module", jit.get_cached_module.ffcx)
    fem.form(forms[0], jit_options=options)  # FFCx 0.11's lookup: the probe sees its listing
    assert listings
