"""Declarative base class for this project's pythonfmu slaves.

A slave declares its interface once, as a table of :class:`Var` rows, and
implements two hooks: :meth:`DeclaredSlave.initialize` (check parameters,
compute the outputs) and :meth:`DeclaredSlave.step` (advance one
communication step). The base class supplies what pythonfmu 0.7 does not:

* no exception escapes to the native layer (pythonfmu turns any escaping
  exception into fmi2Fatal and frees the Python instance). A failed
  initialisation is logged with status fmi2Error and every later doStep
  returns fmi2Discard; a failed step is rolled back, logged and returns
  fmi2Discard (the only non-fatal status pythonfmu 0.7 can return);
* outputs are checked to be finite after every step (never a NaN);
* the FMU state is the whole instance ``__dict__`` (minus pythonfmu's own
  bookkeeping), so get/set FMU state restores all internal state, not only
  the registered variables;
* units, descriptions, min/max and ModelStructure dependencies reach
  modelDescription.xml (see :mod:`toggle.fmu_build`).

State convention: attributes that :meth:`step` changes must be rebound, not
mutated in place (floats, tuples, frozen dataclasses), so the per-step
rollback snapshot can be a cheap shallow copy.
"""

from __future__ import annotations

import copy
import math
import pickle
from dataclasses import dataclass
from typing import Any, ClassVar
from xml.etree.ElementTree import Element

from pythonfmu import Fmi2Causality, Fmi2Initial, Fmi2Slave, Fmi2Variability, Real, String
from pythonfmu.enums import Fmi2Status

_DEFAULT_VARIABILITY = {"parameter": "fixed", "input": "continuous", "output": "continuous"}


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

    def to_pythonfmu(self) -> Real | String:
        """The pythonfmu variable object registered for this row."""
        kind = String if self.is_string else Real
        initial = {"parameter": Fmi2Initial.exact, "output": Fmi2Initial.calculated}
        return kind(
            self.name,
            causality=Fmi2Causality[self.causality],
            variability=Fmi2Variability[self.variability or _DEFAULT_VARIABILITY[self.causality]],
            initial=initial.get(self.causality),
            description=self.description,
        )


class DeclaredSlave(Fmi2Slave):
    """pythonfmu slave built from a :class:`Var` table; see the module doc.

    Subclasses set ``VARIABLES``, ``default_experiment`` (a pythonfmu
    ``DefaultExperiment`` with a step size) and optionally ``STATE_EXCLUDE``
    (attribute names of immutable objects that need not be saved with the FMU
    state, e.g. a compiled model), and implement :meth:`initialize` and
    :meth:`step`.
    """

    VARIABLES: ClassVar[tuple[Var, ...]] = ()
    STATE_EXCLUDE: ClassVar[frozenset[str]] = frozenset()
    #: True when :meth:`step` assigns nothing before it can fail and assigns only
    #: finite outputs: the base class then skips its per-step snapshot and check.
    ATOMIC_STEP: ClassVar[bool] = False

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        # pythonfmu's bookkeeping (vars, log_queue, ...) is not model state; the
        # native layer also holds a reference to log_queue, so it is never replaced.
        self._not_state = frozenset(self.__dict__) | {"_not_state"} | self.STATE_EXCLUDE
        self.failure: str | None = None
        self._outputs = tuple(v.name for v in self.VARIABLES if v.causality == "output")
        for var in self.VARIABLES:
            setattr(self, var.name, var.initial_value)
            self.register_variable(var.to_pythonfmu())

    # ---- hooks for subclasses -------------------------------------------------
    def initialize(self) -> None:
        """Check parameters and compute the outputs; raise ValueError naming a bad parameter."""

    def step(self, current_time: float, step_size: float) -> None:
        """Advance the model by one communication step; raise to reject the step."""
        raise NotImplementedError

    # ---- pythonfmu entry points (never raise) ----------------------------------
    def exit_initialization_mode(self) -> None:
        snapshot = dict(self.__dict__)
        try:
            self.initialize()
            self._check_outputs_finite()
        except Exception as exc:  # any exception escaping to pythonfmu becomes fmi2Fatal
            self.__dict__.update(snapshot)  # outputs stay at their finite pre-init values
            self.failure = f"initialisation failed: {exc}"
            self.log(self.failure, Fmi2Status.error)

    def do_step(self, current_time: float, step_size: float) -> bool:
        if self.failure is not None:
            self.log(f"doStep refused, {self.failure}", Fmi2Status.error)
            return False
        snapshot = None if self.ATOMIC_STEP else dict(self.__dict__)
        try:
            self.step(current_time, step_size)
            if snapshot is not None:
                self._check_outputs_finite()
        except Exception as exc:  # reject the step instead of fmi2Fatal
            if snapshot is not None:
                self.__dict__.update(snapshot)
            self.log(f"step at t={current_time:g} s rejected: {exc}", Fmi2Status.discard)
            return False
        return True

    def log(
        self, msg: str, status: Fmi2Status = Fmi2Status.ok, category: str | None = None
    ) -> None:
        """Queue a message for the host's logger (escaped: FMI loggers printf-format it)."""
        super().log(msg.replace("%", "%%"), status, category)

    def _check_outputs_finite(self) -> None:
        bad = [name for name in self._outputs if not math.isfinite(getattr(self, name))]
        if bad:
            raise ValueError(f"non-finite output(s): {', '.join(bad)}")

    # ---- FMU state: everything the instance holds -----------------------------
    def _get_fmu_state(self) -> dict[str, Any]:
        return copy.deepcopy({k: v for k, v in self.__dict__.items() if k not in self._not_state})

    def _set_fmu_state(self, state: dict[str, Any]) -> None:
        # Deep copy: the host may restore the same saved state several times.
        self.__dict__.update(copy.deepcopy(state))

    @staticmethod
    def _fmu_state_to_bytes(state: dict[str, Any]) -> bytes:
        return pickle.dumps(state)

    @staticmethod
    def _fmu_state_from_bytes(state: bytes) -> dict[str, Any]:
        return pickle.loads(state)  # only bytes this FMU serialised

    # ---- model description -----------------------------------------------------
    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's description extended with units, limits and dependencies."""
        from toggle.fmu_build import extend_model_description  # build time only

        root = super().to_xml(model_options or {})
        extend_model_description(root, self.VARIABLES)
        return root
