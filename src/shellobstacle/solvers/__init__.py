"""The solvers of the obstacle problem and their registry by name (:data:`METHODS`)."""

from shellobstacle.solvers.registry import METHODS, Method, register

__all__ = ["METHODS", "Method", "register"]
