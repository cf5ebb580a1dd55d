"""Markdown tables for the reports."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["fmt", "table"]


def fmt(v: Any) -> str:
    """A table cell: floats with four significant digits."""
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def table(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    """A Markdown table of ``rows`` (dicts) in the given columns."""
    head = "| " + " | ".join(columns) + " |\n|" + "---|" * len(columns) + "\n"
    return head + "\n".join("| " + " | ".join(fmt(r[c]) for c in columns) + " |" for r in rows)
