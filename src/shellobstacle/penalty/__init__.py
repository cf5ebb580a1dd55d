"""The penalty of J_κ: its data (:mod:`~shellobstacle.penalty.spec`: κ or ``h^exponent``, the
continuation ladder), κ on a mesh (:mod:`~shellobstacle.penalty.kappa`: the ladder at the mesh
size, the adapt modes, the cellwise scale ρ) and its term at its quadrature points
(:mod:`~shellobstacle.penalty.quadrature`)."""
