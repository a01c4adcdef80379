"""The public API of the FMUs: `build_fmu` (``toggle build-fmu``).

Wraps `fmu_src.build.build_fmu` (the pythonfmu FMU) and
`fmu_src.native_build.build_native_fmu` (the native C FMU); import it from
`fmu_src`. The modules behind it are private by convention.
"""

from __future__ import annotations

from pathlib import Path

from toggle.files import check_writable, check_writable_dir
from toggle.params import ParameterError, load_preset


def fmu_file_name(native: bool = False, fmi_version: int = 2, interface: str = "cs") -> str:
    """The FMU's file name: ``ToggleClamp.fmu`` or ``ToggleClampNative[3][ME|CSME].fmu``.

    Args:
        native: The native C FMU instead of the pythonfmu one.
        fmi_version: 2 or 3 (native only).
        interface: ``"cs"``, ``"me"`` or ``"both"`` (native only).

    Returns:
        The file name `build_fmu` writes into its folder.
    """
    if not native:
        return "ToggleClamp.fmu"
    from fmu_src.native_build import model_name

    return f"{model_name(fmi_version, interface)}.fmu"


def build_fmu(out: str | Path | None = None, preset: str = "chang2021", *, native: bool = False,
              fmi_version: int = 2, interface: str = "cs", overwrite: bool = False) -> Path:
    """Build the clamp's FMU for a preset into a folder.

    Args:
        out: The folder to write the FMU into (created if missing); default the build
            folder ``hil run`` reads (the checkout's ``build/``, else ``./build``).
        preset: A preset's name or TOML path with ``[dynamics]`` and ``[drive]``; its values
            are the FMU parameters' start values.
        native: Build the native FMU (CasADi-generated C, no Python at run time) instead of
            the pythonfmu FMI 2.0 Co-Simulation FMU.
        fmi_version: With ``native``: FMI 2 or 3.
        interface: With ``native``: ``"cs"`` (Co-Simulation), ``"me"`` (Model Exchange) or
            ``"both"``.
        overwrite: Replace an existing FMU of the same name.

    Returns:
        The path of the FMU built, validated by fmpy.

    Raises:
        ParameterError: An FMI version or interface without ``native``, or a bad preset.
        OutputError: An existing FMU without ``overwrite``, or a folder that cannot be
            written.
        RuntimeError: The compiler or fmpy's validator failed.
    """
    if not native and (fmi_version, interface) != (2, "cs"):
        raise ParameterError("FMI version 3 and interface me|both need native=True (the "
                             "pythonfmu FMU is FMI 2.0 Co-Simulation)")
    load_preset(preset)  # an unreadable or invalid preset: told before the build
    from fmu_src.build import build_folder

    out = build_folder() if out is None else Path(out)
    check_writable_dir(out, "out")
    check_writable(out / fmu_file_name(native, fmi_version, interface), "out",
                   force=overwrite)
    if native:
        from fmu_src.native_build import build_native_fmu

        return build_native_fmu(out, preset, fmi_version, interface)
    from fmu_src.build import build_fmu as build_python_fmu

    return build_python_fmu(out, preset=preset)
