"""Adaptive refinement of the membrane obstacle problem: a posteriori indicators
(:mod:`~shellobstacle.adapt.estimator`), Dörfler marking (:mod:`~shellobstacle.adapt.marking`)
and the solve → estimate → mark → refine loop (:mod:`~shellobstacle.adapt.loop`)."""
