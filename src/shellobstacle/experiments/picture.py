"""The 3D picture of an experiment's solution in its folder, and its line in the report.

Each experiment draws one solution it has just solved (its finest mesh, its largest load,
the paper's ε, the last adapted mesh) with :func:`~shellobstacle.post.pictures.write_picture`,
when ``output.pictures`` is on. A resumed run keeps the picture of the run that solved that
solution: a solution read back from a checkpoint is not drawn again.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from mpi4py import MPI

from shellobstacle.config.loader import Config
from shellobstacle.experiments.common import Say
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.progress import phase

__all__ = ["SolutionPicture"]


class SolutionPicture:
    """The picture ``folder/name`` of one solution of an experiment.

    Args:
        cfg: the experiment's config (``output.pictures`` switches the drawing off).
        path: the PNG file.
        say: where the first drawing failure of the run is reported.
    """

    def __init__(self, cfg: Config, path: Path, say: Say) -> None:
        self.enabled = bool(cfg.output.get("pictures", True))
        self.path, self.say = path, say

    def draw(self, problem: PenalizedProblem | Postprocessor, title: str) -> None:
        """Draw the current solution of ``problem`` (collective)."""
        if not self.enabled:
            return
        from shellobstacle.post.pictures import write_picture

        post = problem if isinstance(problem, Postprocessor) else Postprocessor(problem)
        with phase("drawing the 3D picture"):
            picture = write_picture(post, self.path, title)
        if picture.warning is not None:
            self.say(f"warning: {picture.warning}")

    def drawer(self, label: str) -> Callable[[PenalizedProblem], None]:
        """A function drawing a problem's solution with the title ``label``, h and κ."""

        def draw(problem: PenalizedProblem) -> None:
            from shellobstacle.post.pictures import describe, drawn_as_plane

            h, kappa = mesh_size(problem.mesh), float(problem.kappa.value)
            where = "the plane" if drawn_as_plane(problem.obstacle) else describe(problem.obstacle)
            title = f"{label}: the deformed shell over {where}, h = {h:.4g}, κ = {kappa:.3e}"
            self.draw(problem, title)

        return draw

    def markdown(self, alt: str) -> list[str]:
        """The report's image line and a blank line, if the picture exists (collective)."""
        comm = MPI.COMM_WORLD
        drawn = comm.bcast(self.path.is_file() if comm.rank == 0 else None, root=0)
        return [f"![{alt}]({self.path.name})", ""] if drawn else []
