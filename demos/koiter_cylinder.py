# # Koiter's model: a clamped cylindrical panel pressed onto the plane
#
# A cylinder has Gaussian curvature 0, so the membrane model refuses it; Koiter's model adds
# the bending energy (ε³/3) ∫ a^{αβστ} ρ_στ ρ_αβ √a dy and takes any immersed thin shell. ζ_3
# is P2 with C⁰ interior penalties on the facets; one key switches the model. The same
# pressure then also pushes a stiffer, thicker panel, which stays off the plane.

# +
from shellobstacle import (
    Discretization,
    DomainSpec,
    Load,
    Material,
    PenaltySpec,
    Shell,
    Surface,
    solve,
)
from shellobstacle.post.contact import Postprocessor

panel = Surface.from_strings(["y1", "y2", "sqrt(1 - y1**2) - 0.9"])  # 0.1 above x3 = 0
pressure = Load(("0", "0", "Piecewise((-3e-3, r < 0.15), (0, True))"))
domain = DomainSpec("rectangle", corners=((-0.3, -0.4), (0.3, 0.4)), h=0.02)


def contact(epsilon: float) -> dict:
    shell = Shell(panel, Material(epsilon, lam=0.4, mu=0.3), pressure, model="koiter")
    result = solve(shell, domain, PenaltySpec(exponent=3.0), Discretization(degree=2))
    assert result.converged
    return Postprocessor(result.problem).summary()


thin, thick = contact(0.01), contact(0.02)
print(f"ε = 0.01: contact area {thin['contact_area']:.4e}, lowest ζ_3 {thin['zeta3_min']:.4f}")
print(f"ε = 0.02: contact area {thick['contact_area']:.4e}, lowest ζ_3 {thick['zeta3_min']:.4f}")
# -
