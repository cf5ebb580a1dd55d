"""Where a configuration's value came from, the file or a ``--set``, so that an error about it
names the right one (:mod:`shellobstacle.config.loader`)."""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterable, Iterator, Mapping

from shellobstacle.config.schema import SELECTORS
from shellobstacle.geometry.expressions import ExpressionError
from shellobstacle.messages import ConfigError

__all__ = ["Origins", "SectionError", "in_section"]


class Origins:
    """Which ``--set`` gave a key, so that an error names it rather than the file."""

    def __init__(self, source: str, given: Mapping[str, str] | None) -> None:
        self.source = source
        self.given = dict(given or {})

    def of(self, prefix: str) -> str:
        """The ``--set`` that gave ``prefix`` or a key inside it, else the file."""
        for dotted, text in reversed(self.given.items()):
            if dotted == prefix or dotted.startswith(prefix + "."):
                return text
        return self.source

    def named_in(self, message: str, section: str = "", own: Iterable[str] = ()) -> str:
        """The ``--set`` texts whose keys ``message`` names; else, for a message about
        ``section`` that names none of the file's keys ``own`` there (``kind 'file' needs
        path``), the ``--set`` that chose its kind (:data:`SELECTORS`); else the file."""
        texts = [
            text
            for dotted, text in self.given.items()
            if re.search(rf"(?<![\w.]){re.escape(dotted)}(?!\w)", message)
        ]
        selector = SELECTORS.get(section, ("", ""))[0]
        named = any(re.search(rf"\b{re.escape(name)}\b", message) for name in own)
        if not texts and selector in self.given and not named:
            texts = [self.given[selector]]
        return ", ".join(dict.fromkeys(texts)) or self.source


class SectionError(ConfigError):
    """A problem with the objects of ``[section]``, placed (:meth:`Origins.named_in`) by
    :func:`~shellobstacle.config.loader.parse_config`."""

    def __init__(self, message: str, section: str) -> None:
        super().__init__(message)
        self.section = section


@contextlib.contextmanager
def in_section(name: str) -> Iterator[None]:
    """Tag a problem raised inside with the section ``name`` (:class:`SectionError`)."""
    try:
        yield
    except (ValueError, ExpressionError) as err:
        raise SectionError(str(err), name) from None
