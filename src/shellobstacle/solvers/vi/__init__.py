"""The exact solvers of the nodal obstacle problem (docs/model.md §3, §5): the active-set
method and its peers (PETSc's VI Newton, proximal Galerkin) on the bound-constrained quadratic
program with one rotation per node."""
