"""The 3D picture of an experiment's solution in its folder, and its line in the report.

Each experiment draws one solution it has just solved (its finest mesh, its largest load,
the paper's ε, the last adapted mesh) with :func:`~shellobstacle.post.pictures.write_picture`,
when ``output.pictures`` is on. A resumed run keeps the picture of the run that solved that
solution: a solution read back from a checkpoint is not drawn again. When that run was stopped
before it drew it, the report and the log say that the picture is missing and how to get it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from mpi4py import MPI

from shellobstacle.config.loader import Config
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.progress import phase

__all__ = ["SolutionPicture"]

log = logging.getLogger(__name__)


class SolutionPicture:
    """The picture ``folder/name`` of one solution of an experiment.

    Args:
        cfg: the experiment's config (``output.pictures`` switches the drawing off).
        path: the PNG file.

    A drawing that fails, or a picture that is missing, is logged as a warning.
    """

    def __init__(self, cfg: Config, path: Path) -> None:
        self.enabled = bool(cfg.output.get("pictures", True))
        self.path = path
        #: whether this run has drawn (or tried to draw) the solution
        self.attempted = False

    def draw(self, problem: PenalizedProblem | Postprocessor, title: str) -> None:
        """Draw the current solution of ``problem`` (collective)."""
        if not self.enabled:
            return
        from shellobstacle.post.pictures import write_picture

        self.attempted = True
        post = problem if isinstance(problem, Postprocessor) else Postprocessor(problem)
        with phase("drawing the 3D picture"):
            picture = write_picture(post, self.path, title)
        if picture.warning is not None:
            log.warning(picture.warning)

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
        """The report's image line and a blank line, if the picture exists (collective).

        A picture that is missing because this run read its solution back from the records
        of an interrupted run (and so did not draw it) is said missing, in the report and as
        a warning; one whose drawing failed was reported when it failed.
        """
        comm = MPI.COMM_WORLD
        drawn = comm.bcast(self.path.is_file() if comm.rank == 0 else None, root=0)
        if drawn:
            return [f"![{alt}]({self.path.name})", ""]
        if not self.enabled or self.attempted:
            return []
        missing = (
            f"3D picture ({alt}) is missing: this run read its solution back from the records "
            "of an interrupted run (steps/) and does not draw it again; to draw it, run the "
            "command with --overwrite instead of --resume"
        )
        log.warning(f"the {missing}")
        return [f"*The {missing}.*", ""]
