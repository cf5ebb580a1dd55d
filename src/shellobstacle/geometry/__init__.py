"""The shell's middle surface: safe expressions (:mod:`~shellobstacle.geometry.expressions`), θ's
geometry (:mod:`~shellobstacle.geometry.surface`) and their translation to NumPy and UFL
(:mod:`~shellobstacle.geometry.translation`). The theory's assumptions are
:mod:`shellobstacle.checks`."""
