"""Declarative base class for this project's pythonfmu slaves.

A slave declares its interface once, as a table of :class:`Var` rows, and
implements two hooks: :meth:`DeclaredSlave.initialize` (check parameters,
compute the outputs) and :meth:`DeclaredSlave.step` (advance one
communication step), plus :meth:`DeclaredSlave.model_state` and
:meth:`DeclaredSlave.restore_model_state` for what it holds besides its
variables. The base class supplies what pythonfmu 0.7 does not:

* no exception escapes to the native layer (pythonfmu turns any escaping
  exception into fmi2Fatal and frees the Python instance). A failed
  initialisation or step is rolled back and logged with status fmi2Error,
  which the FMI guard (fmu_src/guard/fmi2_guard.c) returns as the call's
  status and delivers whatever the logging state;
* every Real parameter and input is checked against its declared min/max
  (and to be finite) when initialisation ends; outputs are checked to be
  finite after every step (never a NaN);
* outputs read in Initialization Mode are computed from the values set so far;
* the FMU state is plain data (:mod:`fmu_src.state`): every variable plus
  :meth:`model_state`, serialised as checksummed JSON, never pickle; a state
  set is input to validate: every field is checked with the rules of the
  phase it was taken in (before initialisation the values as set so far;
  after it the parameters as initialisation checks them, and the model state
  by :meth:`restore_model_state`), anything else is fmi2Error;
* the variables' getters hold the instance weakly, so freeing the instance
  frees everything it holds at once (no reference cycle left for the
  garbage collector to find at interpreter exit);
* units, descriptions, min/max and ModelStructure dependencies reach
  modelDescription.xml (see :mod:`fmu_src.description`);
* input derivatives (FMI 2.0 ``fmi2SetRealInputDerivatives``, which pythonfmu 0.7
  does not pass on): each Real input has two hidden Real variables after the
  table (value references n + 2 i and n + 2 i + 1 for the i-th input, orders 1
  and 2), absent from modelDescription.xml; the FMI guard sets them when the
  master calls fmi2SetRealInputDerivatives. :meth:`DeclaredSlave.input_derivative`
  reads them; they apply to the next step only (FMI 2.0 section 4.2.2).

State convention: attributes that :meth:`step` changes must be rebound, not
mutated in place (floats, tuples, frozen dataclasses), so the per-step
rollback snapshot can be a cheap shallow copy.
"""

from __future__ import annotations

import math
import weakref
from typing import Any, ClassVar
from xml.etree.ElementTree import Element

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
from pythonfmu.enums import Fmi2Status

from fmu_src import state as fmu_state
from fmu_src.variables import Var, derivative_name, hidden_names

_STATE_KEYS = frozenset({"fmu", "values", "phase", "failure", "model", "derivatives"})


class DeclaredSlave(Fmi2Slave):
    """pythonfmu slave built from a :class:`Var` table; see the module doc.

    Subclasses set ``VARIABLES`` and ``default_experiment`` (a pythonfmu
    ``DefaultExperiment`` with a step size), and implement :meth:`initialize`,
    :meth:`step` and, when they hold more than their variables,
    :meth:`model_state` and :meth:`restore_model_state`.
    """

    VARIABLES: ClassVar[tuple[Var, ...]] = ()
    #: True when :meth:`step` assigns nothing before it can fail and assigns only
    #: finite outputs: the base class then skips its per-step snapshot and check.
    ATOMIC_STEP: ClassVar[bool] = False

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.failure: str | None = None
        self._phase = "instantiated"
        self._ready = False  # exitInitializationMode succeeded (the model state exists)
        self._stale = True  # outputs not computed from the values set since
        self._outputs = tuple(v.name for v in self.VARIABLES if v.causality == "output")
        self._rows = tuple((v.name, v.is_string, v.causality) for v in self.VARIABLES)
        self._names = frozenset(v.name for v in self.VARIABLES)
        self._derivatives: dict[str, float] = {}  # hidden name -> value, for the next step
        owner = weakref.ref(self)
        for var in self.VARIABLES:
            setattr(self, var.name, var.initial_value)
            self.register_variable(var.to_pythonfmu(owner))
        for name in hidden_names(self.VARIABLES):
            self.register_variable(Real(
                name, causality=Fmi2Causality.local, variability=Fmi2Variability.continuous,
                description="hidden: an input derivative set by the FMI guard",
                getter=lambda n=name: owner()._derivatives.get(n, 0.0),
                setter=lambda value, n=name: owner()._derivatives.__setitem__(n, float(value))))

    # ---- hooks for subclasses -------------------------------------------------
    def initialize(self) -> None:
        """Check parameters and compute the outputs; raise ValueError naming a bad parameter."""

    def step(self, current_time: float, step_size: float) -> None:
        """Advance the model by one communication step; raise to reject the step."""
        raise NotImplementedError

    def model_state(self) -> dict[str, Any]:
        """What an initialised slave holds besides its variables, as JSON-able plain data."""
        return {}

    def restore_model_state(self, state: Any) -> None:
        """Check and rebuild what :meth:`model_state` saved (the variables are already set
        and the parameters checked); raise :class:`~fmu_src.state.StateError` naming a
        field no initialised instance could hold."""
        fmu_state.keys(state, frozenset(), "the model state")

    def input_derivative(self, name: str, order: int) -> float | None:
        """The master's derivative of input ``name`` of ``order`` at the step's start, or
        None if it set none for this step."""
        return self._derivatives.get(derivative_name(name, order))

    # ---- pythonfmu entry points (never raise) ----------------------------------
    def _set(self, name: str, value: Any) -> None:
        setattr(self, name, value)
        self._stale = True

    def enter_initialization_mode(self) -> None:
        self._phase = "initialising"

    def exit_initialization_mode(self) -> None:
        if self._initialise():
            self._phase, self._ready = "stepping", True

    def get_real(self, vrs: list[int]) -> list[float]:
        if self._phase == "initialising" and self._stale:
            self._initialise()  # outputs of the values set so far (FMI InitialUnknowns)
        return super().get_real(vrs)

    def _initialise(self) -> bool:
        snapshot = dict(self.__dict__)
        try:
            self._check_ranges()
            self.initialize()
            self._check_outputs_finite()
        except Exception as exc:  # any exception escaping to pythonfmu becomes fmi2Fatal
            self.__dict__.update(snapshot)  # outputs stay at their finite pre-init values
            self.failure = f"initialisation failed: {exc}"[:fmu_state.MAX_TEXT]
            self.log(self.failure, Fmi2Status.error)
            return False
        self.failure, self._stale = None, False
        self.log("initialised: " + ", ".join(
            f"{v.name} = {getattr(self, v.name)!r}" for v in self.VARIABLES
            if v.causality == "parameter"))
        return True

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
            self.log(f"step at t={current_time:g} s rejected: {exc}", Fmi2Status.error)
            return False
        self._derivatives = {}  # they applied to this step
        return True

    def terminate(self) -> None:
        self._phase = "terminated"

    def _check_ranges(self, causalities: tuple[str, ...] = ("parameter", "input")) -> None:
        """Every Real parameter and input (of ``causalities``) finite and within its
        declared min/max."""
        for var in self.VARIABLES:
            if var.causality not in causalities or var.is_string:
                continue
            value = getattr(self, var.name)
            low = -math.inf if var.min is None else var.min
            high = math.inf if var.max is None else var.max
            if not (math.isfinite(value) and low <= value <= high):
                unit = "" if var.unit == "1" else f" {var.unit}"
                raise ValueError(f"{var.causality} {var.name} = {value!r}{unit} is outside "
                                 f"[{low:g}, {high:g}]{unit}")

    def _check_outputs_finite(self) -> None:
        bad = [name for name in self._outputs if not math.isfinite(getattr(self, name))]
        if bad:
            raise ValueError(f"non-finite output(s): {', '.join(bad)}")

    # ---- FMU state: every variable and the model's own data --------------------
    def state_identity(self) -> str:
        """The FMU a state must come from: the slave class (a subclass adds what else must
        match, such as the preset it is built for)."""
        return type(self).__name__

    def _get_fmu_state(self) -> dict[str, Any]:
        return {"fmu": self.state_identity(),
                "values": {v.name: getattr(self, v.name) if v.is_string
                           else fmu_state.encode_real(getattr(self, v.name))
                           for v in self.VARIABLES},
                "phase": self._phase, "failure": self.failure,
                "model": self.model_state() if self._ready else None,
                "derivatives": dict(self._derivatives)}

    def _set_fmu_state(self, state: dict[str, Any] | fmu_state.StateError) -> None:
        snapshot = dict(self.__dict__)
        try:
            if isinstance(state, fmu_state.StateError):  # bytes that did not parse
                raise state
            self._restore(state)
        except Exception as exc:  # (StateError, a plant that fails): never fmi2Fatal
            self.__dict__.clear()
            self.__dict__.update(snapshot)
            self.log(f"FMU state refused: {exc}", Fmi2Status.error)

    def _restore(self, state: Any) -> None:
        """Check every field of ``state`` with the rules of the phase it was taken in, and
        set it; raises :class:`~fmu_src.state.StateError` (or the plant's error) naming
        the first field that no instance of this FMU could hold."""
        state = fmu_state.keys(state, _STATE_KEYS, "the state")
        if state["fmu"] != self.state_identity():
            raise fmu_state.StateError(f"the state was saved by {fmu_state.short(state['fmu'])},"
                                       f" this FMU is {self.state_identity()!r}")
        phase, failure, model = state["phase"], state["failure"], state["model"]
        if phase not in fmu_state.PHASES:
            raise fmu_state.StateError(f"unknown phase {fmu_state.short(phase)} in the state")
        ready = model is not None  # initialised: exitInitializationMode succeeded
        if failure is not None:
            fmu_state.text(failure, "the state's failure message")
        problem = ("no model state" if phase == "stepping" and not ready
                   else "a model state" if phase in ("instantiated", "initialising") and ready
                   else "a failure message" if failure is not None and (
                       ready or phase in ("instantiated", "stepping")) else None)
        if problem:
            raise fmu_state.StateError(f"a state taken in phase {phase} cannot have {problem}")
        values = fmu_state.keys(state["values"], self._names, "the state's values")
        for name, is_string, causality in self._rows:
            raw = values[name]
            setattr(self, name, fmu_state.text(raw, name) if is_string else
                    fmu_state.decode_real(raw, name, finite_only=causality == "output"
                                          or ready and causality == "parameter"))
        derivatives = state["derivatives"]
        allowed = frozenset(hidden_names(self.VARIABLES))
        if not (isinstance(derivatives, dict) and derivatives.keys() <= allowed):
            raise fmu_state.StateError("the state's derivatives must be an object with keys "
                                       f"among {sorted(allowed)}")
        self._derivatives = {k: fmu_state.finite(v, k) for k, v in derivatives.items()}
        self._phase, self.failure, self._ready = phase, failure, ready
        if ready:
            self._check_ranges(("parameter",))  # as exitInitializationMode checked them
            self.restore_model_state(model)
        self._stale = not ready  # Initialization Mode recomputes the outputs when read

    @staticmethod
    def _fmu_state_to_bytes(state: dict[str, Any]) -> bytes:
        return fmu_state.pack(state)

    @staticmethod
    def _fmu_state_from_bytes(data: bytes) -> dict[str, Any] | fmu_state.StateError:
        try:  # never raise: pythonfmu would return fmi2Fatal and free the instance
            return fmu_state.unpack(data)
        except fmu_state.StateError as exc:
            return exc  # refused, with this message, when the master sets it

    # ---- model description -----------------------------------------------------
    def to_xml(self, model_options: dict[str, str] | None = None) -> Element:
        """pythonfmu's description extended with units, limits and dependencies."""
        import importlib

        # build time only, in the building Python: by a name the bundling leaves alone
        description = importlib.import_module("fmu_src.description")
        root = super().to_xml(model_options or {})
        description.extend_model_description(root, self.VARIABLES, self.initial_dependencies())
        return root

    def initial_dependencies(self) -> dict[str, tuple[str, ...]] | None:
        """Build time: each output's dependencies in Initialization Mode (inputs and
        parameters), or None for "every known"."""
        return None
