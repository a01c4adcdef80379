"""ModelStructure of every build against the dependencies of the generated code (issue 39).

The dependencies are derived here from CasADi's sparsity of the functions the native
build generates to C (fmu_src.native_build.plant_functions, all four variants) and of the
core's Model Exchange equations, never from a hand list; every declared output,
derivative and initial unknown must list exactly those (a missing ``dependencies``
attribute, meaning "every known", fails too). A few physical facts are checked on top, so
that a sparsity routine that lost a dependency could not pass.
"""

from __future__ import annotations

import zipfile
from xml.etree.ElementTree import fromstring

import pytest
from fmu_support import built_fmu
from native_support import native_build

from fmu_src.native_build import structure_dependencies
from toggle.plant import PlantOutputs, configure


@pytest.fixture(scope="module")
def derived():
    return structure_dependencies(configure("chang2021"))


def _declared(fmu) -> tuple[str, dict[str, dict[str, tuple[str, ...] | None]]]:
    """(fmiVersion, {section: {name: dependency names, or None if undeclared}})."""
    with zipfile.ZipFile(fmu) as zf:
        root = fromstring(zf.read("modelDescription.xml"))
    version = root.get("fmiVersion")
    if version == "2.0":
        variables = [sv.get("name") for sv in root.find("ModelVariables")]
        name_of = {str(i + 1): n for i, n in enumerate(variables)}
        sections = {s: root.find(f"ModelStructure/{s}") for s in
                    ("Outputs", "Derivatives", "InitialUnknowns")}
        items = {s: [(u.get("index"), u.get("dependencies")) for u in node]
                 for s, node in sections.items() if node is not None}
    else:
        name_of = {v.get("valueReference"): v.get("name") for v in root.find("ModelVariables")}
        tags = {"Outputs": "Output", "Derivatives": "ContinuousStateDerivative",
                "InitialUnknowns": "InitialUnknown"}
        items = {s: [(u.get("valueReference"), u.get("dependencies"))
                     for u in root.find("ModelStructure") if u.tag == tag]
                 for s, tag in tags.items()}
    return version, {s: {name_of[key]: None if deps is None else
                         tuple(name_of[d] for d in deps.split())
                         for key, deps in rows} for s, rows in items.items() if rows}


BUILDS = [("native", 2, "cs"), ("native", 2, "me"), ("native", 2, "both"),
          ("native", 3, "cs"), ("native", 3, "me"), ("native", 3, "both"), ("clamp", 2, "cs")]


@pytest.mark.parametrize(("kind", "fmi_version", "interface"), BUILDS)
def test_every_unknown_declares_the_dependencies_of_the_generated_code(
        kind, fmi_version, interface, derived):
    fmu = built_fmu("clamp") if kind == "clamp" else native_build(fmi_version, interface)
    _, declared = _declared(fmu)
    me = interface != "cs"
    outputs = list(PlantOutputs._fields)
    want_outputs = {n: derived.run[n] if me else () for n in outputs}
    assert declared["Outputs"] == want_outputs
    if me:
        assert declared["Derivatives"] == {d: derived.run[d] for d in
                                           ("der(x)", "der(velocity)", "der(slip_state)")}
    else:
        assert "Derivatives" not in declared
    locals_ = ("slip_state", "der(x)", "der(velocity)", "der(slip_state)") if me else ()
    assert declared["InitialUnknowns"] == {n: derived.init[n] for n in (*outputs, *locals_)}


def test_the_derived_dependencies_hold_the_physics(derived):
    """The drive lag puts x_cmd into the acceleration and what depends on it (input force,
    motor torque) in Model Exchange; positions depend on the position state only; the
    clamp force on x and velocity (platen friction), never on x_cmd; at initialisation the
    clamp force depends on the mold's position and on link 8's error."""
    assert derived.run["acceleration"] == ("x", "velocity", "x_cmd")
    assert "x_cmd" in derived.run["input_force"] and "x_cmd" in derived.run["motor_torque"]
    for name in ("x", "platen_position", "toggle_angle", "asymmetry"):
        assert derived.run[name] == ("x",)
    assert "x_cmd" not in derived.run["clamp_force"]
    assert derived.run["der(velocity)"] == ("x", "velocity", "x_cmd")
    assert {"x_cmd", "x_contact", "delta_r8"} <= set(derived.init["clamp_force"])
    assert derived.init["velocity"] == () and derived.init["x"] == ("x_cmd",)


@pytest.mark.parametrize(("kind", "fmi_version", "interface"), BUILDS)
def test_every_real_has_a_unit_and_the_attributes_of_its_quantity(kind, fmi_version, interface):
    """Every Real a unit (the derivatives included); lengths, speeds and forces a quantity
    and a display unit (mm, mm/s, kN); x and velocity their nominal; slip_state in
    [-1, 1]."""
    fmu = built_fmu("clamp") if kind == "clamp" else native_build(fmi_version, interface)
    with zipfile.ZipFile(fmu) as zf:
        root = fromstring(zf.read("modelDescription.xml"))
    if fmi_version == 2:
        reals = {sv.get("name"): sv.find("Real").attrib for sv in root.find("ModelVariables")
                 if sv.find("Real") is not None}
    else:
        reals = {v.get("name"): v.attrib for v in root.find("ModelVariables")
                 if v.tag == "Float64" and v.get("name") != "time"}
    assert all(a.get("unit") for a in reals.values()), reals
    for name, display in (("x", "mm"), ("velocity", "mm/s"), ("clamp_force", "kN")):
        assert reals[name].get("displayUnit") == display and reals[name].get("quantity")
    assert float(reals["x"]["nominal"]) == 1e-3 and float(reals["velocity"]["nominal"]) == 0.1
    if interface != "cs":
        assert (reals["slip_state"]["min"], reals["slip_state"]["max"]) == ("-1.0", "1.0")
        assert reals["der(slip_state)"]["unit"] == "1/s"
