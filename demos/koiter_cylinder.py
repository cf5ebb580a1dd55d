# # Koiter's model: a clamped cylindrical panel pressed onto the plane
#
# A cylinder has Gaussian curvature 0, so the membrane model refuses it; Koiter's model adds
# the bending energy (ε³/3) ∫ a^{αβστ} ρ_στ ρ_αβ √a dy and takes any immersed thin shell. ζ_3
# is P2 with C⁰ interior penalties on the facets; one key switches the model. The same
# pressure then also pushes a stiffer, thicker panel, which stays off the plane.

# +
import matplotlib.pyplot as plt

from shellobstacle import (
    Config,
    Discretization,
    DomainSpec,
    Load,
    Material,
    PenaltySpec,
    Shell,
    Surface,
    solve,
)
from shellobstacle.post.sections import cross_section

panel = Surface.from_strings(["y1", "y2", "sqrt(1 - y1**2) - 0.9"])  # 0.1 above x3 = 0
pressure = Load(("0", "0", "Piecewise((-3e-3, r < 0.15), (0, True))"))
domain = DomainSpec("rectangle", corners=((-0.3, -0.4), (0.3, 0.4)), h=0.02)


def press(epsilon: float):
    shell = Shell(panel, Material(epsilon, lam=0.4, mu=0.3), pressure, model="koiter")
    result = solve(Config(shell, domain, Discretization(degree=2), PenaltySpec(exponent=3.0)))
    assert result.converged
    return result


results = {epsilon: press(epsilon) for epsilon in (0.01, 0.02)}
thin, thick = (r.post.summary() for r in results.values())
print(f"ε = 0.01: contact area {thin['contact_area']:.4e}, lowest ζ_3 {thin['zeta3_min']:.4f}")
print(f"ε = 0.02: contact area {thick['contact_area']:.4e}, lowest ζ_3 {thick['zeta3_min']:.4f}")
# -

# Both panels across the cylinder's axis (the line y2 = 0): the thin one lies on the plane
# under the load, the thick one stops above it.

# +
fig, ax = plt.subplots(figsize=(6.4, 3.4), constrained_layout=True)
for i, (epsilon, result) in enumerate(results.items()):
    section = cross_section(result.problem, axis="y1", at=0.0)
    if i == 0:
        ax.plot(section.reference[:, 0], section.height_reference, "--", color="0.4", label="θ")
    ax.plot(section.deformed[:, 0], section.height_deformed, label=f"ε = {epsilon}")
ax.axhline(0.0, color="k", lw=2)
ax.set(xlabel="x₁", ylabel="height above the plane x·q")
ax.legend()
plt.show()
# -
