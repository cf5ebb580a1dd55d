"""The contact zone: Newton's steps condensed onto the dofs around the active points.

:mod:`.graph` (index sets on sparsity patterns), :mod:`.condensation` (``K_II`` factorized
once per zone, the Schur complement, exact solves with the Jacobian), :mod:`.reduced` (the
penalized problem on the zone alone, the model Newton steps on), :mod:`.contact_zone` (which
dofs form the zone, and when it is rebuilt).
"""
