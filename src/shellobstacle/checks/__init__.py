"""The theory's assumptions checked on a shell's data (docs/model.md §3, §8, §10): θ, its
derivatives and the load finite (:mod:`~shellobstacle.checks.finiteness`), then an immersion,
ellipticity, the reference shell strictly admissible and facing the obstacle, a thin shell
(:mod:`~shellobstacle.checks.assumptions`). They read the surface, the material and the
obstacle, so they sit above :mod:`shellobstacle.geometry` and :mod:`shellobstacle.obstacle`."""
