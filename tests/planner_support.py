"""What the planner's tests (tests/test_planner*.py) share: the stroke's duration, the
SM-55's assumed masses and a torque-speed curve that binds on chang2021. The planned
stroke they start from is tests/conftest.py's ``chang_plan`` fixture."""

from __future__ import annotations

#: The duration of the planned strokes, s.
DURATION = 3.0
#: Assumed masses of the SM-55 (its preset has no [dynamics]): crosshead, links, platen, guides.
SM55_MASSES = {"crosshead": 40.0, "links": 120.0, "platen": 500.0, "guide_damping": 2000.0}
#: A torque-speed curve that binds on chang2021 (its drive needs ~0.03 N m at full
#: acceleration, mostly for the rotor's and screw's 52 kg reflected mass).
STEEP = ((0.0, 0.03), (25.0, 0.02), (50.0, 0.012))
