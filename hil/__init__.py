"""Hardware-in-the-loop layer: one plant interface, the FMU or the real rig over serial.

The public API is :func:`run_on_rig`, :func:`read_run` and the :class:`Run` they return
(:mod:`hil.api`, loaded on first use); every other module here is private by convention.

Rooms, each importing only the ones listed before it (tests/import_graph.py ROOMS): ``link``
(the protocol and the host's serial driver), ``host`` (plant back-ends, homing, experiments,
recording, response surfaces, bring-up), ``emulators`` (the MCU model, the firmware's host
build, QEMU, the rehosted board), ``panel`` (the web front panel), ``cli`` (the ``hil``
command) and ``api`` (the public functions above, over the command's own run).
"""

from toggle import lazy_exports

_EXPORTS = {"run_on_rig": ".api", "read_run": ".api", "Run": ".api",
            "RecordingError": ".host.recording", "RunStoppedError": ".host.backends"}
__all__ = list(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
