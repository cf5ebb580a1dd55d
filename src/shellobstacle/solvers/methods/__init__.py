"""The package's methods (:data:`~shellobstacle.solvers.registry.METHODS`), one small class
each; they import their solvers when they solve."""
