"""The live status line: the running phases on a terminal, nothing in logs, pipes, CI or -q.

The terminal is a pseudo-terminal (:mod:`pty`) holding the command's stdin, stdout and stderr,
as an interactive shell would.
"""

from __future__ import annotations

import fcntl
import os
import pty
import re
import select
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

from mpi4py import MPI

import pytest

from shellobstacle import progress
from shellobstacle.cli.main import main

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="terminals of one process")
EXAMPLES = Path(__file__).parents[2] / "examples"
SMALL = EXAMPLES / "small.toml"
ESCAPE = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


def _in_terminal(args: list[str], env: dict[str, str] | None = None) -> tuple[int, str]:
    """``python -m shellobstacle ARGS`` on a 150-column pseudo-terminal: exit code, output."""
    environ = {k: v for k, v in os.environ.items() if k != "CI"}
    environ |= {"TERM": "xterm-256color", "COLUMNS": "150"} | (env or {})
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 150, 0, 0))
    proc = subprocess.Popen(
        [sys.executable, "-m", "shellobstacle", *args],
        stdin=slave,
        stdout=slave,
        stderr=slave,
        env=environ,
    )
    os.close(slave)
    chunks, deadline = [], time.monotonic() + 300
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the other side is closed: the process has ended
                break
            if not chunk:
                break
            chunks.append(chunk)
        elif proc.poll() is not None:
            break
    else:
        proc.kill()
    code = proc.wait(timeout=60)
    os.close(master)
    return code, b"".join(chunks).decode("utf-8", "replace")


def _status_lines(output: str) -> list[str]:
    """The texts the status line showed (each drawing ends with ``\\r`` and an erase)."""
    drawn = re.findall(r"([^\r\n]*)\r\x1b\[2K", output)
    return [ESCAPE.sub("", d) for d in drawn]


def test_phases_nest_and_end_with_their_block() -> None:
    assert progress._stack == []
    with progress.phase("outer") as outer:
        with progress.phase("inner"):
            progress.note("step 1")
            assert [p.text for p in progress._stack] == ["outer", "inner"]
            assert progress._stack[-1].detail == "step 1"
        assert progress._stack == [outer] and outer.detail == ""
        with pytest.raises(KeyError), progress.phase("failing"):
            raise KeyError("x")
        assert progress._stack == [outer]
    assert progress._stack == []
    progress.note("no phase: nothing happens")
    assert progress._stack == []


class _Terminal:
    def isatty(self) -> bool:
        return True


def test_a_status_line_only_on_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setenv("TERM", "xterm")
    monkeypatch.setattr(sys, "stderr", _Terminal())
    assert progress.on_terminal()
    assert not progress.on_terminal(quiet=True)
    monkeypatch.setenv("CI", "true")
    assert not progress.on_terminal()
    monkeypatch.delenv("CI")
    monkeypatch.setenv("TERM", "dumb")
    assert not progress.on_terminal()
    monkeypatch.setenv("TERM", "xterm")
    monkeypatch.setattr(sys, "stderr", None)  # no stderr at all
    assert not progress.on_terminal()


def test_logs_and_pipes_get_plain_lines_only(tmp_path: Path, capfd: pytest.CaptureFixture) -> None:
    """Under pytest stderr is a file: the lines as in log.txt, no status, no escape codes."""
    out = tmp_path / "run"
    args = ["solve", str(SMALL), "-o", str(out), "--set", "domain.h=0.08"]
    assert main([*args, "--set", "output.pictures=false"]) == 0
    err = capfd.readouterr().err
    log = (out / "log.txt").read_text()
    for text in (err, log):
        assert "\x1b" not in text and "\r" not in text
        assert "compiling the forms" not in text  # a phase, not a line
    assert err.splitlines() == log.splitlines()
    assert "κ 1/" in err and "done: κ" in err


def test_a_terminal_shows_the_running_phases(tmp_path: Path) -> None:
    """solve on a terminal: the log lines, and between them the status line naming the
    phases; the status is gone when the command ends, and log.txt holds the plain lines."""
    out = tmp_path / "run"
    code, output = _in_terminal(["solve", str(SMALL), "-o", str(out), "--set", "domain.h=0.06"])
    assert code == 0, output
    shown = "\n".join(_status_lines(output))
    for phase in (
        "meshing the disk (h = 0.06)",
        "› gmsh (",
        "compiling the forms (",
        "κ 1/",
        "writing the ParaView files (",
        "drawing the 3D picture (",
    ):
        assert phase in shown, f"{phase!r} was not shown: {shown}"
    assert re.search(r"^[⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏] \d+ s  ", shown, re.M)  # spinner, time since the start
    plain = ESCAPE.sub("", output).replace("\r\n", "\n")
    assert "] done: κ" in plain
    assert output.rstrip().endswith("\x1b[2K")  # the status line erased at the end
    log = (out / "log.txt").read_text()
    assert "\x1b" not in log and "compiling the forms" not in log and "done: κ" in log


def test_quiet_on_a_terminal_prints_nothing(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["solve", str(SMALL), "-o", str(out), "-q", "--set", "domain.h=0.08"]
    code, output = _in_terminal([*args, "--set", "output.pictures=false"])
    assert code == 0
    assert output == ""
    assert "done: κ" in (out / "log.txt").read_text()


def test_an_experiment_on_a_terminal_shows_its_steps_and_ci_does_not(tmp_path: Path) -> None:
    args = ["experiment", "load", str(EXAMPLES / "paraboloid.toml"), "--values", "0,40"]
    args += ["--set", "domain.h=0.08", "--set", "output.pictures=false"]
    code, output = _in_terminal([*args, "-o", str(tmp_path / "tty")])
    assert code == 0, output
    shown = "\n".join(_status_lines(output))
    assert "batch 3: ell = 0 (1/2) (" in shown and "batch 3: ell = 40 (2/2) (" in shown
    code, output = _in_terminal([*args, "-o", str(tmp_path / "ci")], env={"CI": "true"})
    assert code == 0
    assert _status_lines(output) == [] and "\x1b" not in output
    assert "batch 3: ell = 40: contact area" in output
