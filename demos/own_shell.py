# # A shell of your own: any elliptic surface θ
#
# The middle surface is given by its chart θ(y) = (y1, y2, f(y)) as strings; its metric,
# curvature and Christoffel symbols are derived symbolically. Here an elliptic paraboloid
# over a disk, loaded by a Gaussian pressure. The solve refuses a surface that is not
# elliptic on ω, or one that already crosses the plane.

# +
from shellobstacle import Config, DomainSpec, Load, Material, PenaltySpec, Shell, Surface, solve

shell = Shell(
    Surface.from_strings(["y1", "y2", "0.3 - 0.8*y1**2 - 0.5*y2**2"]),
    Material(epsilon=1e-3, lam=0.4, mu=0.012),
    Load(("0", "0", "-5e-5*exp(-100*r**2)")),
)
domain = DomainSpec("disk", radius=0.5, h=0.04)
result = solve(Config(shell, domain, penalty=PenaltySpec(kappa=1e-8)))
print(f"converged {result.converged}, Newton steps {result.iterations}")
# -

# +
summary = result.post.summary()
print(f"contact area {summary['contact_area']:.4e}, lowest ζ_3 {summary['zeta3_min']:.4e}")
