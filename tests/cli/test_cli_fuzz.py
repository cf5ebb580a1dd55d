"""Property tests of the command line: any argument list is accepted or refused in one line.

:func:`shellobstacle.cli.main` runs in-process on argument lists drawn by hypothesis: every
command with valid and invalid options and values (numbers as text, comma lists, unknown
choices, conflicting flags), ``--set`` with random keys and TOML values, config paths (missing,
a directory, binary, empty, random TOML, the examples) and output paths (a file, a path under
a file, folders holding results, user files or an interrupted run, new folders).

The work that starts after every check is replaced by stubs (:data:`WORK`) that raise
:class:`Accepted`: the config, the options, the memory estimate and the output folder are
checked for real, nothing is meshed or solved. For each argument list:

* argparse's own refusals end with ``SystemExit(2)`` and its usage message;
* ``main`` returns one of the documented exit codes, never after a traceback or an
  "internal error";
* exit 2 prints exactly one stderr line ``shellobstacle: error: ...``;
* a refused command changes no file and makes no folder; files of the user's and results
  are never modified, whatever the outcome.
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

from mpi4py import MPI

import pytest
from conftest import examples
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from shellobstacle.cli.main import main
from shellobstacle.config.schema import SCHEMA

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="fuzz tests run serially")

EXAMPLES = Path(__file__).parents[2] / "examples"
EXAMPLE_FILES = sorted(EXAMPLES.glob("*.toml"))
EXAMPLE_TEXTS = [p.read_text() for p in EXAMPLE_FILES]
EXIT_CODES = {0, 1, 2, 3, 130}
FUZZ = settings(
    max_examples=examples(600),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)


class Accepted(BaseException):
    """A stub of the work was reached: the command passed every check (not an Exception,
    so that ``main`` does not report it as a bug)."""


#: the functions that start the work once everything is checked (module, name)
WORK = [
    ("shellobstacle.api", "solve"),
    ("shellobstacle.api", "make_mesh"),
    ("shellobstacle.experiments.reproduce", "reproduce"),
    ("shellobstacle.experiments.penalty", "run_penalty"),
    ("shellobstacle.experiments.mesh", "run_mesh"),
    ("shellobstacle.experiments.solvers", "run_solvers"),
    ("shellobstacle.experiments.koiter_limit", "run_koiter_limit"),
    ("shellobstacle.experiments.load", "run_load"),
]


def _reached(*_args: object, **_kwargs: object) -> None:
    raise Accepted


@pytest.fixture(scope="module", autouse=True)
def _no_work() -> Iterator[None]:
    import importlib

    # every module first: one imported under the stubs would keep them in its names
    for module, _ in WORK:
        importlib.import_module(module)
    with pytest.MonkeyPatch.context() as mp:
        for module, name in WORK:
            mp.setattr(importlib.import_module(module), name, _reached)
        INTERRUPTED.update(_interrupted_runs())
        yield


def _interrupted_runs() -> dict[str, str]:
    """The files of two runs stopped after their first step (as ``--resume`` finds them):
    ``interrupted/`` of ``experiment penalty small.toml`` and ``interrupted-fast/`` of
    ``reproduce``."""
    small = str(EXAMPLES / "small.toml")
    runs = {
        "interrupted": ["experiment", "penalty", small, "-q"],
        "interrupted-fast": ["reproduce", "-q"],
    }
    files: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, argv in runs.items():
            folder = Path(tmp) / name
            assert run([*argv, "-o", str(folder)])[0] == "accepted"
            (folder / "steps" / "step-0.json").write_text("{}\n")
            for path in folder.rglob("*"):
                if path.is_file():
                    files[str(path.relative_to(tmp))] = path.read_text()
    return files


# --------------------------------------------------------------------------- the workspace

#: files and folders in the working directory of every example
USER_FILES = {"file.txt": "notes\n", "user/notes.txt": "mine\n"}
RESULT_FILES = {"results/summary.json": "{}\n", "results/log.txt": "done\n"}
TREE = {
    **USER_FILES,
    **RESULT_FILES,
    "empty.toml": "",
    "corrupt/steps/meta.json": "[1, 2]\n",  # JSON, not the record of a run
    "corrupt/steps/step-0.json": "{}\n",
    "small.toml": (EXAMPLES / "small.toml").read_text(),
    "huge.msh": "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 1e15 1 1e15\n",
    "nan.msh": "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\nnan nan 1 3\n",
    "leftover/log.txt": "failed early\n",
    "leftover/config.toml": "[domain]\n",
}
FOLDERS = ["emptydir", "folder.toml"]
LINKS = {"link": "results", "dangling": "nowhere"}
#: the files of interrupted runs (:func:`_interrupted_runs`)
INTERRUPTED: dict[str, str] = {}
BINARY = b"\x00\xff\xfe\x89PNG\r\n\x1a\n"


@contextlib.contextmanager
def workspace(config_text: str) -> Iterator[Path]:
    """A fresh folder ``root/ws`` (the working directory) with :data:`TREE`, a binary file
    and ``random.toml`` holding ``config_text``; yields ``root`` (``..`` is inside it)."""
    old = Path.cwd()
    with tempfile.TemporaryDirectory(prefix="shellobstacle-cli-fuzz-") as tmp:
        root = Path(tmp)
        ws = root / "ws"
        for name, text in {**TREE, **INTERRUPTED}.items():
            (ws / name).parent.mkdir(parents=True, exist_ok=True)
            (ws / name).write_text(text)
        for name in FOLDERS:
            (ws / name).mkdir()
        (ws / "binary.toml").write_bytes(BINARY)
        for name, target in LINKS.items():
            (ws / name).symlink_to(target)
        (ws / "random.toml").write_text(config_text, encoding="utf-8", errors="surrogateescape")
        os.chdir(ws)
        try:
            yield root
        finally:
            os.chdir(old)


def snapshot(root: Path) -> dict[str, bytes | str | None]:
    """Every path under ``root`` with its content (None for a folder, the target of a
    symbolic link)."""

    def content(p: Path) -> bytes | str | None:
        if p.is_symlink():
            return os.readlink(p)
        return None if p.is_dir() else p.read_bytes()

    return {str(p.relative_to(root)): content(p) for p in sorted(root.rglob("*"))}


# --------------------------------------------------------------------------- strategies

#: numbers as a user may type them (argparse's float() takes "nan", "inf", "1e999", " 1 ")
SPECIAL_NUMBERS = ["0", "-0", "-1", "nan", "inf", "-inf", "1e999", "1e-320", "1e308", "1e-200"]
PLAIN_NUMBERS = ["0.5", "1", "1.5", "2", "3", "0.1", "0.07", "1e-3", "12", "8", "9", "200"]
NUMBER = st.one_of(
    st.sampled_from(PLAIN_NUMBERS),
    st.sampled_from([*SPECIAL_NUMBERS, "", " ", "abc", "1,2", "0x10", "1_0", "½", "1e"]),
    st.floats().map(repr),
    st.integers(-(10**30), 10**30).map(str),
)
NUMBER_LIST = st.one_of(
    NUMBER,
    st.lists(NUMBER, min_size=0, max_size=5).map(",".join),
    st.sampled_from([",", ",,", "1,,2", "0.5," * 201, ",".join(["1"] * 201)]),
)
WORDS = st.one_of(
    st.sampled_from(["gauss", "vertex", "ell", "P", "foo", "", "gauss,vertex", "vertex,gauss"]),
    st.text(max_size=8),
)

#: safe relative output names (``..`` stays inside the fuzz root); \udcff is a byte that is
#: not UTF-8, as Linux hands it to Python
OUTPUT_NAMES = [
    *(  # noqa: SIM905
        "new new/deeper file.txt file.txt/sub user results interrupted interrupted-fast corrupt "
        "leftover link dangling dangling/sub emptydir folder.toml . .. ../outside binary.toml "
        "-dash ü-ñ"
    ).split(),
    "",
    " ",
    "out\udcff",
]
OUTPUT = st.one_of(
    st.sampled_from(OUTPUT_NAMES),
    st.sampled_from(OUTPUT_NAMES),
    st.text(alphabet="ab-_ .\n", max_size=6),
)

CONFIG_NAMES = [
    *"missing.toml folder.toml emptydir binary.toml empty.toml file.txt".split(),  # noqa: SIM905
    "results/summary.json",
    "",
    "no\udcffutf8.toml",
]
CONFIG = st.one_of(
    st.sampled_from([str(p) for p in EXAMPLE_FILES]),
    st.sampled_from([str(p) for p in EXAMPLE_FILES]),
    st.sampled_from(["random.toml"] * 3 + ["small.toml"] * 3 + CONFIG_NAMES),
)
#: ``--set``s that make the domain a mesh file (relative to small.toml in the workspace)
MESH_FILES = ["huge.msh", "nan.msh", "emptydir", "binary.toml", "missing.msh", ".", "../ws"]
FILE_DOMAIN = st.sampled_from(MESH_FILES).map(
    lambda path: ["--set", "domain.kind=file", "--set", f"domain.path={path}"]
)

#: every key of the schema, the one users set most first (hypothesis favours the first)
DOTTED = sorted(
    (f"{section}.{key}" for section, keys in SCHEMA.items() for key in keys),
    key=lambda k: (k != "domain.h", k),
)
SET_KEYS = st.one_of(
    st.sampled_from(DOTTED),
    st.sampled_from(DOTTED).map(lambda k: k[:-1]),  # a typo
    st.sampled_from(
        ["load.parameters.ell", "load.parameters.P", "domain", "domain.h.x", "x.y", ".h", "a."]
    ),
    st.text(alphabet="abdehkmnopstx._ =", max_size=12),
)
#: TOML values (valid, of wrong types, malformed: a --set takes those as bare strings)
TOML_TEXTS = (  # noqa: SIM905
    '0.05|0.1|1|2|-1|0|nan|inf|-inf|1e999|1e-200|1e-320|true|"newton"|active-set|koiter|file|'
    'rectangle|iterative|[1, 2]|[0, 0, 1]|["0", "0", "-1e-3"]|[[0, 0], [1, 0], [0, 1]]|'
    "[[-0.3, -0.4], [0.3, 0.4]]|{ ell = 1 }|{ a = 1|[|\"unterminated|'|1979-05-27||="
).split("|")
TOML_VALUES = st.one_of(st.sampled_from([*TOML_TEXTS, str(10**400)]), NUMBER, st.text(max_size=10))
TOML_NUMBER = st.one_of(st.sampled_from(PLAIN_NUMBERS + SPECIAL_NUMBERS[:6]), st.floats().map(repr))


def _typed(dotted: str) -> st.SearchStrategy[str]:
    """A TOML value of the key's type (a plausible ``--set``), in range or not."""
    section, _, name = dotted.partition(".")
    key = SCHEMA[section][name]
    t = key.type
    if t == "float":
        return TOML_NUMBER
    if t == "int":
        return st.integers(-2, 10).map(str)
    if t == "bool":
        return st.sampled_from(["true", "false"])
    if t == "str":
        return st.sampled_from([*(f'"{c}"' for c in key.choices), '"mesh.msh"', '"y1"'])
    if t == "table":
        return st.sampled_from(["{ ell = 1 }", "{ P = 3e-3 }", "{}", "{ r = 1 }"])
    if t == "points":
        return st.sampled_from(["[[0, 0], [1, 0], [0, 1]]", "[[-0.3, -0.4], [0.3, 0.4]]", "[]"])
    if t == "options":  # PETSc options: valid, misspelled, refused by PETSc, not a name
        return st.sampled_from(
            ['{ ksp_type = "cg" }', "{}", "{ ksp_tyep = 1 }", '{ pc_type = "x" }', '{ "-a" = 1 }']
        )
    n = int(t[t.index("[") + 1 : -1])
    return st.lists(TOML_NUMBER, min_size=n, max_size=n).map(lambda v: f"[{', '.join(v)}]")


PLAUSIBLE_SET = st.sampled_from(DOTTED).flatmap(lambda k: _typed(k).map(lambda v: f"{k}={v}"))
SET_ITEMS = st.one_of(
    PLAUSIBLE_SET,
    PLAUSIBLE_SET,
    st.tuples(SET_KEYS, TOML_VALUES).map("=".join),
    st.sampled_from(["domain.h", "=1", "domain.h==1", "noequals"]),
)


@st.composite
def config_texts(draw: st.DrawFn) -> str:
    """An example config with lines deleted, replaced or added, or random text."""
    if draw(st.integers(0, 5)) == 0:
        return draw(st.text(max_size=60))
    lines = draw(st.sampled_from(EXAMPLE_TEXTS)).splitlines()
    for _ in range(draw(st.integers(0, 3))):
        i = draw(st.integers(0, len(lines)))
        how = draw(st.sampled_from(["delete", "replace", "insert", "garbage"]))
        if how == "delete" and i < len(lines):
            del lines[i]
            continue
        if how == "garbage":
            new = draw(st.text(max_size=20))
        else:
            new = draw(st.tuples(SET_KEYS.map(lambda k: k.rpartition(".")[2]), TOML_VALUES))
            new = " = ".join(new)
        if how == "replace" and i < len(lines):
            lines[i] = new
        else:
            lines.insert(i, new)
    return "\n".join(lines) + "\n"


#: option → values, by command; flags have None
SOLVE = {"--set": SET_ITEMS, "-o": OUTPUT, "--overwrite": None, "--force": None, "-q": None}
CHECK = {"--set": SET_ITEMS, "--force": None, "-q": None}
EXPERIMENT = {
    **SOLVE,
    **dict.fromkeys(["--resume", "-v"]),
    **dict.fromkeys(["--start", "--step", "--q-max", "--tol", "--exponent"], NUMBER),
    **dict.fromkeys(["--edge-h", "--edge-width"], NUMBER),
    **dict.fromkeys(["--q", "--values", "--sizes", "--epsilons"], NUMBER_LIST),
    **dict.fromkeys(["--quadratures", "--parameter"], WORDS),
    "--refinements": st.one_of(st.integers(-3, 12).map(str), NUMBER),
}
REPRODUCE = {"-o": OUTPUT, "--overwrite": None, "--resume": None, "--full": None, "-v": None}
BATCHES = ["penalty", "mesh", "load", "solvers", "koiter-limit"]


@st.composite
def command_lines(draw: st.DrawFn) -> list[str]:
    """A command, its positional arguments and 0-6 options in random order."""
    command = draw(
        st.sampled_from(["solve", "check", "experiment", "experiment", "reproduce", "other"])
    )
    if command == "other":
        return draw(
            st.sampled_from(
                [["config-reference"], ["bogus"], [], ["solve"], ["experiment", "x", "c.toml"]]
            )
        )
    head = [command]
    table = {"solve": SOLVE, "check": CHECK, "experiment": EXPERIMENT}.get(command, REPRODUCE)
    if command == "experiment":
        head.append(draw(st.sampled_from([*BATCHES, "penalty", "mesh", "load"])))
    if command != "reproduce":
        head.append(draw(CONFIG))
    options: list[list[str]] = []
    if "--set" in table and draw(st.integers(0, 9)) == 0:
        options.append(draw(FILE_DOMAIN))
    for _ in range(draw(st.integers(0, 6))):
        flag = draw(st.sampled_from(sorted(table)))
        values = table[flag]
        if values is None:
            options.append([flag])
        elif draw(st.booleans()):
            options.append([flag, draw(values)])
        else:
            options.append([f"{flag}={draw(values)}"])
    return head + [arg for option in draw(st.permutations(options)) for arg in option]


# --------------------------------------------------------------------------- the property


def run(argv: list[str]) -> tuple[str, object, str]:
    """``main(argv)`` with stdout and stderr as on a UTF-8 terminal, and the warnings that
    escape it written to stderr as Python does: ("returned", code, stderr), ("accepted",
    None, stderr) or ("argparse", SystemExit's code, stderr)."""
    out = io.TextIOWrapper(io.BytesIO(), encoding="utf-8")
    err = io.TextIOWrapper(io.BytesIO(), encoding="utf-8", errors="backslashreplace")
    with (
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
        warnings.catch_warnings(record=True) as escaped,
    ):
        warnings.simplefilter("always")
        try:
            outcome, code = "returned", main(argv)
        except Accepted:
            outcome, code = "accepted", None
        except SystemExit as stop:
            outcome, code = "argparse", stop.code
        for w in escaped:
            err.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno))
        out.flush()
        err.flush()
    return outcome, code, err.buffer.getvalue().decode("utf-8")  # type: ignore[attr-defined]


def check_command(argv: list[str], config_text: str = "") -> str:
    """Run ``argv`` in a fresh workspace and assert the properties; returns the outcome."""
    with workspace(config_text) as root:
        before = snapshot(root)
        outcome, code, err = run(argv)
        after = snapshot(root)
    assert "Traceback" not in err and "internal error" not in err, (argv, err)
    if outcome == "argparse":
        assert code == 2 and err.startswith("usage:"), (argv, code, err)
    elif outcome == "returned":
        assert code in EXIT_CODES, (argv, code, err)
        if code == 2:
            lines = err.splitlines()
            assert len(lines) == 1 and lines[0].startswith("shellobstacle: error:"), (argv, err)
    for name in (*USER_FILES, *RESULT_FILES):
        assert after.get(f"ws/{name}") == before[f"ws/{name}"], (argv, name)
    if outcome != "accepted" and code != 0:
        assert after == before, (argv, set(after) ^ set(before), err)
    return outcome if outcome == "accepted" else f"{outcome} {code}"


PAPER, SMALL = str(EXAMPLES / "paper.toml"), str(EXAMPLES / "small.toml")
KOITER, PARABOLOID = str(EXAMPLES / "cylinder_koiter.toml"), str(EXAMPLES / "paraboloid.toml")
Q_WARNS = "--set=obstacle.q=[0.5, 0.5, 0.5]"  # normalized, with a warning

#: command lines the fuzzing found crashing or printing more than one line, the message's key
#: words, and the fix the message names
FOUND = [
    (["solve", PAPER, "--set", "domain.h=1e-200"], "gives more vertices than", "larger h"),
    (["check", KOITER, "--set", "domain.h=1e-200"], "gives more vertices than", "larger h"),
    (["experiment", "solvers", PAPER, "--sizes", "1e-200"], "--sizes: h = 1e-200", "larger h"),
    (["experiment", "koiter-limit", PAPER, "--edge-h", "1e-200"], "edge_h = 1e-200", "larger h"),
    (["reproduce", "-o", "out\udcff"], "'out\\xff' is not UTF-8 text", "rename"),
    (["solve", KOITER, "--set=discretization.degree=\r0"], "degree=\\r0", "must be 1 or 2"),
    (["reproduce", "--resume", "-o", "corrupt"], "is not the record of a run", "--overwrite"),
    (["check", KOITER, "--set=domain.h=1.5", Q_WARNS], "exceeds the domain's diameter", "h="),
    (["solve", SMALL, Q_WARNS, "-o", "file.txt"], "'file.txt' is a file", "another -o"),
    (
        ["experiment", "load", PARABOLOID, "--set", "solver.method=active-set"],
        "'active-set' has no κ",
        "set solver.method = 'newton'",
    ),
    (["solve", SMALL, "-o", "dangling"], "symbolic link to 'nowhere'", "create that folder"),
    (["solve", SMALL, "-o", "dangling/sub"], "symbolic link to 'nowhere'", "another -o"),
    (
        ["solve", "small.toml", "--set", "domain.kind=file", "--set", "domain.path=emptydir"],
        "mesh file",
        "is a directory: give a gmsh .msh file",
    ),
    (
        ["check", "small.toml", "--set", "domain.kind=file", "--set", "domain.path=none.msh"],
        "ws/none.msh' does not exist",
        "give a gmsh .msh file",
    ),
]


@pytest.mark.parametrize(("argv", "problem", "fix"), FOUND, ids=lambda v: str(v)[:50])
def test_found_refusals_name_the_problem_and_the_fix(argv: list[str], problem: str, fix: str):
    """Exit 2 with one line naming the problem and the fix; nothing is made or changed."""
    with workspace("") as root:
        before = snapshot(root)
        outcome, code, err = run(argv)
        assert snapshot(root) == before
    assert (outcome, code) == ("returned", 2), err
    assert err.startswith("shellobstacle: error:") and len(err.splitlines()) == 1, err
    assert problem in err and fix in err, err


@pytest.mark.slow  # 600 command lines (6000 with HYPOTHESIS_PROFILE=random): a minute
@FUZZ
@given(command_lines(), config_texts())
@example(FOUND[0][0], "")
def test_command_lines_are_accepted_or_refused_in_one_line(argv: list[str], text: str) -> None:
    """Every drawn command line passes its checks or is refused cleanly (module docstring)."""
    event(check_command(argv, text))
