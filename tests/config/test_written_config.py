"""A result folder's ``config.toml`` (``to_toml`` of the resolved config) reads back to it."""

from __future__ import annotations

from cli_helpers import write_config

from shellobstacle.config.loader import load_config, to_toml


def test_written_config_reads_back_to_the_resolved_config(tmp_path) -> None:
    """A result folder's config.toml (``to_toml`` of the resolved config) reads back to it,
    a multi-line expression and a table of parameters included."""
    p = ["0", "0", "Piecewise((-P*(1 - r**2),\n           r < 0.06), (0, True))"]
    cfg = load_config(write_config(tmp_path, {"load.p": p, "load.parameters": {"P": 0.003}}))
    assert "\n" in cfg.resolved["load"]["p"][2]
    saved = tmp_path / "config.toml"
    saved.write_text(to_toml(cfg.resolved))
    assert load_config(saved).resolved == cfg.resolved
