# # The paper's problem from its configuration file
#
# A spherical cap over a disk, pressed down near its apex by a load of compact support
# (Meixner & Piersanti 2024, section 10; `examples/paper.toml`). The configuration is
# loaded and validated, the assumptions of the theory are checked, and the penalized
# problem with κ = h^1.5 is solved by Newton's method. The script is a jupytext "light"
# notebook: run it with `python demos/paper_problem.py` or open it with jupytext.

# +
from pathlib import Path

from shellobstacle import load_config, solve_config
from shellobstacle.post.contact import Postprocessor

ROOT = Path(__file__).resolve().parents[1] if "__file__" in globals() else Path.cwd()
cfg = load_config(ROOT / "examples" / "paper.toml", ["domain.h=0.04"])
print(cfg.shell.surface.description)
# -

# `solve_config` meshes ω, checks the assumptions (ellipticity of θ, the reference shell
# above the plane, the load's regularity) and runs the continuation in κ.

# +
result = solve_config(cfg)
for check in result.checks:
    print(f"{check.name:34s} {check.quantity} = {check.value:.3g} ({check.requirement})")
print(f"h = {result.h:.4f}, κ = {result.kappa:.3e}, Newton steps {result.iterations}")
# -

# The contact region: where the deformed shell touches the plane (to the penalty's
# tolerance), its area on the surface (with `√a dy`) and projected onto ω.

summary = Postprocessor(result.problem).summary()
for key in ("contact_area", "contact_area_projected", "max_violation", "zeta3_min"):
    print(f"{key:24s} {summary[key]:.4e}")
