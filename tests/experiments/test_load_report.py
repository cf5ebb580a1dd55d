"""The load experiment's report describes the problem it solved: on a user's shell the user's
load, no central refinement and no loaded-disk line; the paper's wording for the paper's load."""

from __future__ import annotations

from cli_helpers import EXAMPLES, run, serial

from shellobstacle.config.loader import load_config
from shellobstacle.mesh.domains import DomainSpec


def _horizontal_line_labels(monkeypatch) -> list[str]:
    """The labels of every horizontal line matplotlib draws from now on."""
    import matplotlib.axes

    labels: list[str] = []
    draw = matplotlib.axes.Axes.axhline

    def axhline(self, *args, **kwargs):
        labels.append(str(kwargs.get("label", "")))
        return draw(self, *args, **kwargs)

    monkeypatch.setattr(matplotlib.axes.Axes, "axhline", axhline)
    return labels


@serial
def test_load_experiment_describes_the_users_problem(capsys, tmp_path, monkeypatch) -> None:
    """On a user's shell: the user's load, no central refinement, no loaded-disk line."""
    labels = _horizontal_line_labels(monkeypatch)
    out = tmp_path / "load"
    args = ["--set", "domain.h=0.1", "--values", "0,20", "-o", str(out), "-q"]
    args += ["--set", "output.pictures=false"]
    code, _, err = run(capsys, "experiment", "load", str(EXAMPLES / "paraboloid.toml"), *args)
    assert code == 0, err
    report = (out / "report.md").read_text()
    assert "g_ℓ" not in report and "0.295" not in report and "0.06" not in report
    assert "refined near the centre" not in report
    assert "p = (`0`, `0`, `Piecewise((-ell*1e-6" in report
    assert "grow monotonically with ell" in report or "grows with ell" in report
    assert labels and not any("loaded disk" in label for label in labels), labels


def test_load_experiment_keeps_the_papers_wording() -> None:
    from shellobstacle.experiments import load
    from shellobstacle.experiments.reproduce import PAPER_CONFIG

    cfg = load.batch3_config(load_config(PAPER_CONFIG))
    assert load.is_paper_load(cfg.shell.load)
    assert not load.is_paper_load(load_config(EXAMPLES / "paraboloid.toml").shell.load)
    assert load._load_text(cfg.shell.load, True).startswith("g_ℓ = −(2ε/25)")
    spec = DomainSpec("disk", h=0.05, radius=0.5, central_h=0.01, central_radius=0.1)
    assert "refined near the centre" in load._refined_text(spec)
    assert load._refined_text(DomainSpec("disk", h=0.05)) == ""


def test_only_the_papers_load_draws_its_loaded_disk(tmp_path, monkeypatch) -> None:
    from shellobstacle.experiments import load

    labels = _horizontal_line_labels(monkeypatch)
    study = load.LoadStudy("ell", 0.1, 1e-3, 100)
    study.rows = [
        {"ell": v, "contact_area_nodal": a, "contact_area_nodal_projected": a}
        for v, a in [(0.0, 0.01), (10.0, 0.02)]
    ]
    load.plot_contact_area(study, tmp_path / "paper.png", paper_load=True)
    assert any("loaded disk" in label for label in labels)
    labels.clear()
    load.plot_contact_area(study, tmp_path / "user.png", paper_load=False)
    assert not any("loaded disk" in label for label in labels)
