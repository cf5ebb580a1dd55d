# # The penalty error against the exact solution
#
# The penalized solution ζ_κ converges to the solution ζ of the variational inequality
# (Theorem 5.1), with ‖ζ − ζ_κ‖ ≤ C √κ under the regularity of the paper's section 6
# (Theorem 7.1). On a fixed mesh the discrete problem is a finite-dimensional quadratic
# program: once ζ_κ's active set is the exact one, ζ_κ solves a linear system whose penalty
# term is 1/κ times a fixed matrix, and ζ_κ − ζ falls like κ. The exact discrete solution
# (κ = 0, the constraint at the vertices) comes from the primal–dual active-set solver; the
# penalized problems use the same vertex constraint, so the difference is the penalty's
# error alone.
# One compiled problem serves every κ (κ is a `dolfinx.fem.Constant`), and each Newton
# solve warm-starts from the previous κ.

# +
import itertools
import math
from pathlib import Path

import matplotlib.pyplot as plt

from shellobstacle import Discretization, exact_solution, load_config, make_mesh
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.norms import DifferenceNorms
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver

# examples/ of the repository: beside the script's folder (or a notebook's working folder)
HERE = (Path(__file__).parent if "__file__" in globals() else Path.cwd()).resolve()
EXAMPLES = next(d / "examples" for d in (HERE, *HERE.parents) if (d / "examples").is_dir())
cfg = load_config(EXAMPLES / "paper.toml", ["domain.h=0.04"])
mesh = make_mesh(cfg.domain)
disc = Discretization(penalty_quadrature="vertex")
exact, kkt = exact_solution(cfg.shell, mesh, disc)
print(f"exact solver: {kkt.iterations} linear solves, KKT {kkt.relative_kkt}")
# -

# +
problem = PenalizedProblem(cfg.shell, mesh, disc)
solver, norms = NewtonSolver(problem), DifferenceNorms(problem.V)
kappas = [1e-3, 1e-4, 1e-5, 1e-6]
errors = []
for kappa in kappas:
    (step,) = continuation(problem, solver, [kappa])
    errors.append(norms(problem.zeta, exact)["vm"])
    print(f"κ = {kappa:.0e}: {step.iterations} Newton steps, ‖ζ_κ − ζ‖_VM = {errors[-1]:.3e}")
pairs = zip(itertools.pairwise(errors), itertools.pairwise(kappas), strict=True)
rates = [math.log(e0 / e1) / math.log(k0 / k1) for (e0, e1), (k0, k1) in pairs]
print("observed orders in κ:", ", ".join(f"{r:.2f}" for r in rates))

# The errors on logarithmic axes, against a line of slope 1 through the first one.

# +
fig, ax = plt.subplots(figsize=(5.0, 3.6), constrained_layout=True)
ax.loglog(kappas, errors, "o-", label="‖ζ_κ − ζ‖_VM")
ax.loglog(kappas, [errors[0] * k / kappas[0] for k in kappas], "--", color="0.5", label="∝ κ")
ax.set(xlabel="κ", ylabel="error in V_M")
ax.legend()
plt.show()
# -
