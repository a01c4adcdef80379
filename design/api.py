"""The public API of clamp design: `search_designs` (``toggle design``).

Wraps `design.search.run_search` (NSGA-II/III or a design of experiments over Dask,
resumable), `design.output.write_results`, `design.placement.place` and the
figures; import it from `design`. The modules behind it are private by convention.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from design.targets import Targets, load_targets, targets_from_dict
from toggle.params import ParameterError


@dataclass(frozen=True)
class DesignSearch:
    """What a design search found and wrote.

    Attributes:
        targets: The targets searched for.
        front: The Pareto set of the feasible designs (each with ``key``, ``metrics``).
        evaluations: Every candidate evaluated, feasible or not.
        computed: How many this call computed (the rest came from ``out``'s record).
        files: The files written, by kind (``pareto_csv``, ``front_png``, ...).
        placements: The base preset's reference designs placed against the front.
    """

    targets: Targets
    front: list[Any]
    evaluations: list[Any]
    computed: int
    files: dict[str, Path]
    placements: list[Any] = field(default_factory=list)

    @property
    def feasible(self) -> list[Any]:
        """The evaluated designs that meet every target and limit."""
        return [e for e in self.evaluations if e.feasible]


def search_designs(targets: str | Path | dict[str, Any] | Targets,
                   out: str | Path = "design-out", *, doe: str | None = None,
                   samples: int = 0, generations: int = 20, population: int = 40,
                   seed: int = 0, workers: int | None = None, scheduler: str | None = None,
                   front_duty: bool = True, figures: bool = True,
                   progress: bool = False, connect_timeout: float = 10.0) -> DesignSearch:
    """Search the double-toggle family for a designer's targets and write the Pareto set.

    Args:
        targets: A targets TOML file (see ``design/examples/``), its table as a dict, or
            loaded `design.targets.Targets`.
        out: The results folder; an interrupted search of the same targets there resumes.
        doe: ``"lhs"`` or ``"sobol"``: a design of experiments of ``samples`` candidates
            instead of the genetic algorithm.
        samples: Candidates of the design of experiments.
        generations: NSGA-II/III generations.
        population: NSGA-II/III population.
        seed: The search's seed (a seed replays a search).
        workers: Local Dask worker processes; 0 evaluates in this process; default one per
            free core (none for a search under 200 candidates).
        scheduler: An existing Dask scheduler's address, ``tcp://HOST:PORT``.
        front_duty: Plan the front designs' strokes and molding cycles (RMS torque,
            energy; about 1.4 s a design).
        figures: Write ``front.png`` and ``parallel.png``.
        progress: Show a progress bar on stderr.
        connect_timeout: Seconds to wait for ``scheduler``.

    Returns:
        The Pareto front, every evaluation and the files written in ``out``.

    Raises:
        ParameterError: Bad targets, or targets that no design meets (naming the
            constraint that binds).
    """
    from design.output import write_results
    from design.placement import place
    from design.search import binding_constraint, run_search

    if isinstance(targets, dict):
        targets = targets_from_dict(targets)
    elif not isinstance(targets, Targets):
        targets = load_targets(targets)
    if doe is not None and samples < 1:
        raise ParameterError(f"a design of experiments needs samples >= 1, got {samples!r}")
    out = Path(out)
    result = run_search(targets, out, generations=generations, population=population,
                        doe_method=doe, samples=samples, seed=seed, scheduler=scheduler,
                        workers=workers, progress=progress, front_duty=front_duty,
                        connect_timeout=connect_timeout)
    if not result.front:
        raise ParameterError(f"no design meets the targets of {targets.origin}: "
                             f"{binding_constraint(result.evaluations)}")
    files = write_results(out, targets, result.front, result.evaluations)
    placements = place(targets, result.front)
    if figures:
        from design.figures import front_figure, parallel_figure

        files["front_png"] = front_figure(out / "front.png", targets.objectives,
                                          result.feasible, result.front, placements)
        files["parallel_png"] = parallel_figure(out / "parallel.png", targets.objectives,
                                                result.front, placements)
    return DesignSearch(targets, result.front, result.evaluations, result.evaluated, files,
                        placements)
