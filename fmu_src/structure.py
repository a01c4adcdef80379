"""The native FMU's model as CasADi functions, and ModelStructure's dependencies from them.

:func:`plant_functions` evaluates :func:`toggle.plant.plant_outputs` on CasADi symbols
(the functions :mod:`fmu_src.native_build` generates to C);
:func:`structure_dependencies` reads every output's and derivative's direct dependencies
off their sparsity, for the native and the pythonfmu build alike (issue 39).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, NamedTuple

import casadi as ca

from toggle.params import DIMENSIONS, DYNAMICS_PARAMETERS, HALVES, PAPER_NAMES, symbolic_copy
from toggle.plant import PlantConfig, PlantOutputs, plant_outputs

#: Model Exchange's continuous states: (state, derivative name, derivative unit); x and
#: velocity are outputs, the slip state and the derivatives are locals after the table.
ME_STATES = (("x", "der(x)", "m/s"), ("velocity", "der(velocity)", "m/s2"),
             ("slip_state", "der(slip_state)", "1/s"))
#: The [dynamics] fields by FMU parameter name, first in the generated functions' ``masses``.
MASS_FIELDS = {name: field for name, (field, _, _) in DYNAMICS_PARAMETERS.items()}
#: The drive's inertias, after the masses in the generated functions' ``masses`` input.
DRIVE_FIELDS = ("rotor_inertia", "screw_inertia")
N_MASSES = len(MASS_FIELDS) + len(DRIVE_FIELDS)
#: Names of the generated functions, indexed by (mold, unequal halves) in the C wrapper.
VARIANTS = ("tgc_free_equal", "tgc_free_unequal", "tgc_mold_equal", "tgc_mold_unequal")


class _SymbolicHalf(NamedTuple):
    """Eight symbolic dimensions of one half, in :data:`toggle.params.DIMENSIONS` order.

    Two halves are equal only if they are the same object, so the plant's
    ``Mechanism.symmetric`` decides between the generated variants.
    """

    r1: Any
    r2: Any
    r3: Any
    r4a: Any
    r4b: Any
    r4c: Any
    r5: Any
    e: Any

    def as_tuple(self) -> tuple[Any, ...]:
        return tuple(self)

    def __eq__(self, other: object) -> bool:
        return self is other

    def __hash__(self) -> int:
        return id(self)


def plant_functions(cfg: PlantConfig) -> list[ca.Function]:
    """The plant as CasADi functions (xvaz[4], lower[8], upper[8], mu, masses, x_contact);
    xvaz: position, velocity, acceleration and the pin friction's slip state; masses: the
    fields of :data:`MASS_FIELDS`, then the drive's inertias (:data:`DRIVE_FIELDS`)."""
    xva = ca.SX.sym("xvaz", 4)
    p_lower, p_upper = (ca.SX.sym(h, len(DIMENSIONS)) for h in HALVES)
    mu, masses, x_contact = (ca.SX.sym("mu"), ca.SX.sym("masses", N_MASSES),
                             ca.SX.sym("x_contact"))
    lower = _SymbolicHalf(*ca.vertsplit(p_lower))
    values = ca.vertsplit(masses)
    dynamics = symbolic_copy(cfg.dynamics, **dict(zip(MASS_FIELDS.values(), values)))
    drive = symbolic_copy(cfg.mechanism.drive, **dict(zip(DRIVE_FIELDS,
                                                         values[len(MASS_FIELDS):])))
    functions = []
    for name in VARIANTS:
        upper = lower if name.endswith("_equal") else _SymbolicHalf(*ca.vertsplit(p_upper))
        mech = dataclasses.replace(cfg.mechanism, lower=lower, upper=upper, dynamics=dynamics,
                                   drive=drive)
        mold = "_mold" in name  # the no-mold variant ignores its x_contact input
        sym_cfg = symbolic_copy(cfg, mechanism=mech, mu=mu, x_contact=None)
        outs = plant_outputs(xva[0], xva[1], xva[2], sym_cfg, x_contact if mold else None,
                             slip_state=xva[3])
        functions.append(ca.Function(
            name, [xva, p_lower, p_upper, mu, masses, x_contact],
            [ca.vertcat(*[ca.SX(o) for o in outs])],
            ["xvaz", "lower", "upper", "mu", "masses", "x_contact"], ["y"], {"cse": True}))
    return functions


class Dependencies(NamedTuple):
    """ModelStructure's direct dependencies, by variable name: ``run``, of each output and
    state derivative on the continuous states and the input in Model Exchange; ``init``, of
    each initial unknown on the input and the parameters in Initialization Mode."""

    run: dict[str, tuple[str, ...]]
    init: dict[str, tuple[str, ...]]


def _depends(expr: Any, symbols: Sequence[Any], names: Sequence[str]) -> list[tuple[str, ...]]:
    """For each entry of ``expr``, the names of the scalar ``symbols`` it depends on
    (CasADi's structural sparsity of the Jacobian)."""
    jac = ca.jacobian(expr, ca.vertcat(*symbols)).sparsity()
    return [tuple(names[j] for j in sorted({jac.get_col()[k] for k in range(jac.nnz())
                                             if jac.row()[k] == i}))
            for i in range(expr.numel())]


def structure_dependencies(cfg: PlantConfig) -> Dependencies:
    """The dependencies of every output and derivative, from the sparsity of the generated
    plant functions (:func:`plant_functions`, all variants united) and of the core's Model
    Exchange equations: der(x) = velocity, der(velocity) = w^2 (x_cmd - x) - 2 zeta w
    velocity (the drive lag), der(slip_state) = (sign(v) - z) |v| / slip_distance (Dahl)."""
    functions = plant_functions(cfg)
    x, v, z, u, w, zeta = (ca.SX.sym(n) for n in ("x", "v", "z", "u", "w", "zeta"))
    a = w * w * (u - x) - 2 * zeta * w * v  # clamp_core.c lag_acceleration
    states = ("x", "velocity", "slip_state", "x_cmd")
    errors = [ca.SX.sym(f"delta_{PAPER_NAMES[half][dim]}") for half in HALVES
              for dim in DIMENSIONS]
    mu, x_contact = ca.SX.sym("mu"), ca.SX.sym("x_contact")
    masses = [ca.SX.sym(n) for n in (*MASS_FIELDS, *DRIVE_FIELDS)]
    mech = cfg.mechanism
    nominal = mech.lower.as_tuple() + mech.upper.as_tuple()
    dims = [n + e for n, e in zip(nominal, errors)]
    known = [u, *errors, mu, *masses, x_contact]
    known_names = ["x_cmd", *(str(e) for e in errors), "mu", *(str(m) for m in masses),
                   "x_contact"]
    run: dict[str, set[str]] = {}
    init: dict[str, set[str]] = {}
    for f in functions:
        params = (ca.vertcat(*dims[:len(DIMENSIONS)]), ca.vertcat(*dims[len(DIMENSIONS):]),
                  mu, ca.vertcat(*masses), x_contact)
        y_run = f(ca.vertcat(x, v, a, z), *params)
        y_init = f(ca.vertcat(u, 0, 0, 0), *params)
        for name, deps in zip(PlantOutputs._fields, _depends(y_run, [x, v, z, u], states)):
            run.setdefault(name, set()).update(deps)
        for name, deps in zip(PlantOutputs._fields, _depends(y_init, known, known_names)):
            init.setdefault(name, set()).update(deps)
    slip = (ca.sign(v) - z) * ca.fabs(v) / cfg.asymmetry.slip_distance
    for (_, der, _), expr in zip(ME_STATES, (v, a, slip)):
        run[der] = set(_depends(expr, [x, v, z, u], states)[0])
        init[der] = set()  # the derivatives are 0 at rest, where initialisation puts the drive
    init["slip_state"] = set()  # relaxed at initialisation
    order = {n: i for i, n in enumerate(states + tuple(known_names))}
    return Dependencies(*({k: tuple(sorted(d, key=order.__getitem__)) for k, d in m.items()}
                          for m in (run, init)))
