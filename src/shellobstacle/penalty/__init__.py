"""The penalty of J_κ: its data (:mod:`~shellobstacle.penalty.spec`: κ or ``h^exponent``, the
continuation ladder), κ on a mesh (:mod:`~shellobstacle.penalty.kappa`: the ladder at the mesh
size, the adapt modes, the cellwise scale ρ) and its quadrature rule
(:mod:`~shellobstacle.penalty.rule`: the UFL measure, the reference points, the quadrature
space). Its term as operators on the rule's points, which the solvers use, is
:mod:`~shellobstacle.solvers.quadrature_penalty`."""
