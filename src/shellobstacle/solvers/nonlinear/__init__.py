"""Solvers for the non-convex energy of Koiter's nonlinear model (docs/model.md §11.1–11.2).

* :mod:`.tangent`: the tangent stiffness, factorized by MUMPS' symmetric indefinite LDLᵀ, with
  its inertia (how many negative pivots) and a diagonal shift;
* :mod:`.newton`: Newton's method made to decrease the energy (a shift where the tangent is
  indefinite, a backtracking line search on the energy itself);
* :mod:`.load_stepping`: the load factor from 0 to 1 in steps that cut and grow, the path's
  record, and the limit point (:class:`~.load_stepping.LimitPointError`).

They take any problem with the attributes of
:class:`~shellobstacle.models.nonlinear_koiter.NonlinearKoiterProblem` (:class:`.newton.Energy`).
"""
