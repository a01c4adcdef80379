"""The search: pymoo's NSGA-II (NSGA-III from four objectives) or a design of experiments
(Latin hypercube, Sobol) over the batch evaluator, and the Pareto set of what was found.

Both are deterministic for a seed, and the evaluations come from the store when they are
there, so a search run again on the same folder replays what was done (without computing
it again) and goes on where it stopped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from design.objectives import Evaluation, objective_matrix
from design.runner import CONNECT_TIMEOUT, Runner, evaluator_for
from design.store import Store
from design.targets import VARIABLES, Targets
from toggle.params import ParameterError

#: Objective value given to the optimiser for a candidate that has none (infeasible).
_WORST = 1e12
DOE_METHODS = ("lhs", "sobol")


@dataclass
class SearchResult:
    """What a search found: every evaluation it asked for (in order, no repeats) and the
    Pareto set of the feasible ones."""

    targets: Targets
    evaluations: list[Evaluation]
    front: list[Evaluation]
    folder: Path
    evaluated: int  # computed by this run (the rest came from the store)

    @property
    def feasible(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.feasible]


def full_vectors(targets: Targets, free: np.ndarray) -> np.ndarray:
    """Candidate vectors of all :data:`VARIABLES` from values of the free ones."""
    free = np.atleast_2d(free)
    out = np.array([[targets.bounds[v][0] for v in VARIABLES]] * free.shape[0], dtype=float)
    for j, name in enumerate(targets.free):
        out[:, list(VARIABLES).index(name)] = free[:, j]
    return out


def pareto_front(evaluations: Sequence[Evaluation], keys: Sequence[str]) -> list[Evaluation]:
    """The feasible evaluations no other feasible one dominates (one per key)."""
    from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting
    unique = {e.key: e for e in evaluations if e.feasible}
    ok = [e for e in unique.values() if all(math.isfinite(e.metrics.get(k, math.nan))
                                            for k in keys)]
    if not ok:
        return []
    F = objective_matrix(ok, keys)
    front = NonDominatedSorting().do(F, only_non_dominated_front=True)
    return sorted((ok[i] for i in front), key=lambda e: e.key)


def _unique(evaluations: Sequence[Evaluation]) -> list[Evaluation]:
    return list({e.key: e for e in evaluations}.values())


def _bounds(targets: Targets) -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([targets.bounds[v][0] for v in targets.free])
    hi = np.array([targets.bounds[v][1] for v in targets.free])
    return lo, hi


def _check_free(targets: Targets) -> None:
    if not targets.free:
        raise ParameterError(f"{targets.origin}: every variable is fixed ([bounds] low == high):"
                             " nothing to search")


def doe(targets: Targets, runner: Runner, method: str, samples: int, seed: int = 0
        ) -> list[Evaluation]:
    """Evaluate a Latin hypercube or (scrambled) Sobol sample of the free variables."""
    from scipy.stats import qmc
    _check_free(targets)
    if method not in DOE_METHODS:
        raise ParameterError(f"DOE method must be one of {', '.join(DOE_METHODS)}, "
                             f"got {method!r}")
    d = len(targets.free)
    sampler = (qmc.LatinHypercube(d=d, seed=seed) if method == "lhs"
               else qmc.Sobol(d=d, scramble=True, seed=seed))
    unit = sampler.random(samples)
    lo, hi = _bounds(targets)
    return runner.evaluate(full_vectors(targets, lo + unit * (hi - lo)))


def nsga(targets: Targets, runner: Runner, generations: int, population: int,
         seed: int = 0) -> list[Evaluation]:
    """Run NSGA-II (two or three objectives) or NSGA-III (four or more) and return every
    evaluation it asked for."""
    from pymoo.core.problem import Problem
    from pymoo.optimize import minimize
    _check_free(targets)
    keys = targets.objectives
    active = runner_active(runner)
    seen: list[Evaluation] = []
    lo, hi = _bounds(targets)

    class _Clamp(Problem):  # pymoo's batch interface over the runner
        def __init__(self) -> None:
            super().__init__(n_var=len(lo), n_obj=len(keys), n_ieq_constr=len(active),
                             xl=lo, xu=hi)

        def _evaluate(self, X: np.ndarray, out: dict, *args: object, **kwargs: object
                      ) -> None:
            evals = runner.evaluate(full_vectors(targets, X))
            seen.extend(evals)
            F = objective_matrix(evals, keys)
            out["F"] = np.where(np.isfinite(F), F, _WORST)
            out["G"] = np.array([[e.constraints[c] for c in active] for e in evals])

    minimize(_Clamp(), _algorithm(len(keys), population, seed), ("n_gen", generations),
             seed=seed, verbose=False)
    return _unique(seen)


def runner_active(runner: Runner) -> tuple[str, ...]:
    from design.runner import evaluator_for
    return evaluator_for(runner.targets).active


def _partitions(objectives: int, population: int) -> int:
    """Das-Dennis partitions: the most whose directions fit the population."""
    partitions = 1
    while math.comb(partitions + 1 + objectives - 1, objectives - 1) <= population:
        partitions += 1
    return partitions


def _population(objectives: int, population: int) -> int:
    """Candidates per generation (NSGA-III's at least one per reference direction)."""
    if objectives <= 3:
        return population
    return max(population, math.comb(_partitions(objectives, population) + objectives - 1,
                                     objectives - 1))


def _algorithm(objectives: int, population: int, seed: int) -> object:
    if objectives <= 3:
        from pymoo.algorithms.moo.nsga2 import NSGA2
        return NSGA2(pop_size=population)
    from pymoo.algorithms.moo.nsga3 import NSGA3
    from pymoo.operators.selection.tournament import TournamentSelection
    from pymoo.util.ref_dirs import get_reference_directions
    directions = get_reference_directions("das-dennis", objectives,
                                          n_partitions=_partitions(objectives, population))
    return NSGA3(ref_dirs=directions, pop_size=_population(objectives, population),
                 selection=TournamentSelection(func_comp=_by_cv_then_random))


def _by_cv_then_random(pop: object, P: np.ndarray, random_state: np.random.Generator,
                       **kwargs: object) -> np.ndarray:
    """NSGA-III's tournament (pymoo's ``comp_by_cv_then_random``: the smaller constraint
    violation wins, else a random one) drawing from the algorithm's seeded generator:
    pymoo 0.6.2's breaks ties with an unseeded one, so a seed would not replay a search
    (and a resumed search would not find its evaluations)."""
    winners = np.empty(P.shape[0], dtype=int)
    for i, (a, b) in enumerate(P[:, :2]):
        cv_a, cv_b = (float(np.ravel(pop[j].CV)[0]) for j in (a, b))
        if (cv_a > 0 or cv_b > 0) and cv_a != cv_b:
            winners[i] = a if cv_a < cv_b else b
        else:
            winners[i] = random_state.choice([a, b])
    return winners[:, None]


def run_search(targets: Targets, folder: str | Path, *, generations: int = 20,
               population: int = 40, doe_method: str | None = None, samples: int = 0,
               seed: int = 0, scheduler: str | None = None, workers: int | None = None,
               progress: bool = False, connect_timeout: float = CONNECT_TIMEOUT,
               front_duty: bool = True) -> SearchResult:
    """Search for ``targets``, recording every evaluation in ``folder`` as it arrives.

    With ``doe_method`` ("lhs" or "sobol") evaluate ``samples`` candidates of a design of
    experiments; otherwise run the genetic algorithm for ``generations`` of ``population``.
    Then, with ``front_duty`` and a preset the planner can take, the front's designs get
    their planned duty, stroke and molding cycle (:meth:`Runner.with_duty`), recorded too.
    """
    store = Store(folder, targets.digest())
    total = samples if doe_method is not None else generations * _population(
        len(targets.objectives), population)
    with Runner(targets, store, scheduler=scheduler, workers=workers, progress=progress,
                connect_timeout=connect_timeout, total=total) as runner:
        if doe_method is not None:
            evaluations = doe(targets, runner, doe_method, samples, seed)
        else:
            evaluations = nsga(targets, runner, generations, population, seed)
        evaluated = runner.evaluated
        front = pareto_front(evaluations, targets.objectives)
        if front_duty and evaluator_for(targets).plans_duty:
            front = runner.with_duty(front)
            planned = {e.key: e for e in front}
            evaluations = [planned.get(e.key, e) for e in evaluations]
    return SearchResult(targets, evaluations, front, Path(folder), evaluated)


def binding_constraint(evaluations: Sequence[Evaluation]) -> str:
    """Why no candidate is feasible: the constraint still violated by the candidate closest
    to feasible, with how far it misses, and the reason of that candidate."""
    if not evaluations:
        return "no candidates were evaluated"
    best = min(evaluations, key=lambda e: sum(max(v, 0.0) for v in e.constraints.values()))
    worst = max(best.constraints, key=best.constraints.__getitem__)
    return (f"{worst} binds: the candidate closest to feasible (of {len(evaluations)}) misses "
            f"it by {100 * best.constraints[worst]:.3g} % ({best.reason})")

