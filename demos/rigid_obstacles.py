# # Rigid obstacles: a ball, a roller, a formula
#
# The paper presses its cap onto the plane x3 = 0. Any rigid body {g(x) ≥ 0} works the same
# way (docs/model.md §10): here the paper's cap is pressed onto balls whose top touches that
# plane, onto the plane written as a formula, and with its lower face instead of its middle
# surface. A curved obstacle is solved by linearizing its gap at the previous answer until the
# two agree; the result records the passes.

# +
import dataclasses

from shellobstacle import (
    Config,
    DomainSpec,
    Load,
    Material,
    Obstacle,
    PenaltySpec,
    Shell,
    Surface,
    solve,
)

load = "Piecewise((-(2*epsilon/25)*(-5.0*y1**2-5.0*y2**2+0.295), r < 0.06), (0, True))"
cap = Shell(Surface.spherical_cap(1.0, 0.85), Material(1e-3, 0.4, 0.012), Load(("0", "0", load)))
domain, penalty = DomainSpec("disk", radius=0.5, h=0.03), PenaltySpec(exponent=1.5)


def ball(radius: float, **kw) -> Obstacle:
    return Obstacle(kind="sphere", center=(0, 0, -radius), radius=radius, **kw)


cases = {
    "plane x3 = 0": Obstacle(),
    "g = x3 (a formula)": Obstacle(kind="expression", g="x3"),
    "ball R = 0.5": ball(0.5),
    "ball R = 10": ball(10.0),
    "plane, lower face": Obstacle(contact_face="lower"),
}
print(f"{'obstacle':20s} {'passes':>6s} {'Newton':>6s} {'contact area':>12s} {'min ζ_3':>10s}")
rows = {}
for name, obstacle in cases.items():
    shell = dataclasses.replace(cap, obstacle=obstacle)
    result = solve(Config(shell, domain, penalty=penalty))
    area, lowest = result.contact.area, result.post.zeta3_range()[0]
    rows[name] = (result, area, lowest)
    passes = result.extra.get("linearizations", "-")
    print(f"{name:20s} {passes!s:>6s} {result.iterations:6d} {area:12.4e} {lowest:10.5f}")
# -

# The formula `x3` is recognized as a plane (no passes) and gives the plane's numbers. The
# ball of radius 10 is within 1e-4 of the plane (the difference falls like 1/R,
# docs/results/obstacles.md); the small ball touches over a smaller region. The lower face
# stops ε = 0.001 higher.
