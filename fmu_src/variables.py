"""One row of a pythonfmu slave's variable table (:class:`Var`), and the hidden variables
that carry input derivatives: what the slave (:mod:`fmu_src.slave`) registers and the
model description (:mod:`fmu_src.description`) declares.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Variability, Real, String

_DEFAULT_VARIABILITY = {"parameter": "fixed", "input": "continuous", "output": "continuous"}
#: Orders of an input's derivatives a master may set (fmi2SetRealInputDerivatives).
DERIVATIVE_ORDERS = (1, 2)


def derivative_name(name: str, order: int) -> str:
    """The hidden variable that carries input ``name``'s derivative of ``order``."""
    return f"der{order}_{name}"


def hidden_names(variables: tuple[Var, ...] | list[Var]) -> list[str]:
    """The hidden derivative variables registered after the table, in value-reference order."""
    return [derivative_name(v.name, k) for v in variables
            if v.causality == "input" and not v.is_string for k in DERIVATIVE_ORDERS]


@dataclass(frozen=True)
class Var:
    """One row of a slave's variable table (SI units).

    ``start`` is required for parameters and inputs and forbidden for outputs
    (they are ``initial="calculated"``). A ``str`` start makes a String
    parameter, which carries no unit. ``depends_on`` names the inputs an output
    depends on directly (``()``: none, i.e. no direct feedthrough; ``None``:
    all inputs, the conservative FMI default).
    """

    name: str
    causality: str
    unit: str
    description: str
    start: float | str | None = None
    min: float | None = None
    max: float | None = None
    variability: str | None = None
    depends_on: tuple[str, ...] | None = None
    nominal: float | None = None  # the magnitude a master scales its tolerances by

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ValueError(f"variable name {self.name!r} is not a Python identifier")
        if self.causality not in _DEFAULT_VARIABILITY:
            allowed = sorted(_DEFAULT_VARIABILITY)
            raise ValueError(f"{self.name}: causality must be one of {allowed}")
        if not self.description:
            raise ValueError(f"{self.name}: a description is required")
        if (self.start is None) != (self.causality == "output"):
            raise ValueError(f"{self.name}: parameters and inputs need a start, outputs must not")
        if self.depends_on is not None and self.causality != "output":
            raise ValueError(f"{self.name}: only outputs have depends_on")
        if self.is_string and (self.min is not None or self.max is not None):
            raise ValueError(f"{self.name}: a String variable has no min/max")
        if self.min is not None and self.max is not None and not self.min <= self.max:
            raise ValueError(f"{self.name}: min {self.min} > max {self.max}")

    @property
    def is_string(self) -> bool:
        return isinstance(self.start, str)

    @property
    def initial_value(self) -> float | str:
        """Attribute value before initialisation (0.0 for outputs, finite)."""
        return 0.0 if self.start is None else self.start

    def to_pythonfmu(self, owner: weakref.ref) -> Real | String:
        """The pythonfmu variable object registered for this row, reading ``owner()``."""
        kind = String if self.is_string else Real
        initial = {"parameter": Fmi2Initial.exact, "output": Fmi2Initial.calculated}
        name = self.name
        return kind(
            name,
            causality=Fmi2Causality[self.causality],
            variability=Fmi2Variability[self.variability or _DEFAULT_VARIABILITY[self.causality]],
            initial=initial.get(self.causality),
            description=self.description,
            getter=lambda: getattr(owner(), name),
            setter=lambda value: owner()._set(name, value),
        )
