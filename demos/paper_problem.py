# # The paper's problem from its configuration file
#
# A spherical cap over a disk, pressed down near its apex by a load of compact support
# (Meixner & Piersanti 2024, section 10; `examples/paper.toml`). The configuration is
# loaded and validated, the assumptions of the theory are checked, and the penalized
# problem with κ = h^1.5 is solved by Newton's method. The script is a jupytext "light"
# notebook: run it with `python demos/paper_problem.py` or open it with jupytext.

# +
from pathlib import Path

import matplotlib.pyplot as plt

from shellobstacle import load_config, solve
from shellobstacle.post.sections import cross_section

# examples/ of the repository: beside the script's folder (or a notebook's working folder)
HERE = (Path(__file__).parent if "__file__" in globals() else Path.cwd()).resolve()
EXAMPLES = next(d / "examples" for d in (HERE, *HERE.parents) if (d / "examples").is_dir())
cfg = load_config(EXAMPLES / "paper.toml", ["domain.h=0.04"])
print(cfg.shell.surface.description)
# -

# `solve` meshes ω, checks the assumptions (ellipticity of θ, the reference shell
# above the plane, the load's regularity) and runs the continuation in κ.

# +
result = solve(cfg)
for check in result.checks:
    print(f"{check.name:34s} {check.quantity} = {check.value:.3g} ({check.requirement})")
print(f"h = {result.h:.4f}, κ = {result.kappa:.3e}, Newton steps {result.iterations}")
# -

# The contact region: where the deformed shell touches the plane (to the penalty's
# tolerance), its area on the surface (with `√a dy`) and projected onto ω.

summary = result.post.summary()
for key in ("contact_area", "contact_area_projected", "max_violation", "zeta3_min"):
    print(f"{key:24s} {summary[key]:.4e}")

# The shell along the line y2 = 0 near its apex: the height x·q above the plane of the
# deformed middle surface θ + ζ_i a^i and of the reference shell θ. The deformed shell is
# flattened on the plane where the load pushes it.

# +
section = cross_section(result.problem, axis="y1", at=0.0)
fig, ax = plt.subplots(figsize=(6.4, 3.4), constrained_layout=True)
ax.plot(section.reference[:, 0], section.height_reference, "--", color="0.4", label="θ")
ax.plot(section.deformed[:, 0], section.height_deformed, label="θ + ζ_i a^i")
ax.axhline(0.0, color="k", lw=2)
ax.set(xlabel="x₁", ylabel="height above the plane x·q", xlim=(-0.25, 0.25))
ax.legend()
plt.show()
# -
