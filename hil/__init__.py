"""Hardware-in-the-loop layer: one plant interface, the FMU or the real rig over serial.

The public API is :func:`run_on_rig`, :func:`read_run` and the :class:`Run` they return
(:mod:`hil.api`, loaded on first use); every other module here is private by convention.
"""

from hil.interrupts import install_exit_handlers, started_as_hil

# the `hil` command (its console script or `python -m hil.cli`) gets its SIGINT/SIGTERM
# handlers here, before hil.cli's heavy imports: a Ctrl-C in the first second of `hil run`
# printed a KeyboardInterrupt traceback, and a SIGTERM killed it without its exit code 143
if started_as_hil():
    install_exit_handlers()

import os  # noqa: E402
import sys  # noqa: E402

from toggle import lazy_exports  # noqa: E402

if started_as_hil() and sys.argv[1:] == ["--version"] and os.path.basename(
        sys.argv[0]) == "hil":
    # answered before hil.cli's imports (numpy, the back-ends: seconds on a loaded machine),
    # as fast as `toggle --version`; the same text as argparse's version action
    from toggle import __version__

    sys.stdout.write(f"hil {__version__}\n")
    sys.stdout.flush()
    os._exit(0)

_EXPORTS = {"run_on_rig": ".api", "read_run": ".api", "Run": ".api",
            "RecordingError": ".recording", "RunStoppedError": ".backends"}
__all__ = list(_EXPORTS)

__getattr__ = lazy_exports(__name__, _EXPORTS)
