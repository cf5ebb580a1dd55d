"""The penalty of J_κ: its data (:mod:`~shellobstacle.penalty.spec`: κ or ``h^exponent``, the
continuation ladder), κ on a mesh (:mod:`~shellobstacle.penalty.kappa`: the ladder at the mesh
size, the adapt modes, the cellwise scale ρ), its quadrature rule
(:mod:`~shellobstacle.penalty.rule`) and its term at the rule's points
(:mod:`~shellobstacle.penalty.quadrature`)."""
