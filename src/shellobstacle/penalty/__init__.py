"""The penalty term of J_κ at its quadrature points."""
