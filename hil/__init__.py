"""Hardware-in-the-loop layer: one plant interface, the FMU or the real rig over serial."""

from hil.interrupts import install_exit_handlers, started_as_hil

# the `hil` command (its console script or `python -m hil.cli`) gets its SIGINT/SIGTERM
# handlers here, before hil.cli's heavy imports: a Ctrl-C in the first second of `hil run`
# printed a KeyboardInterrupt traceback, and a SIGTERM killed it without its exit code 143
if started_as_hil():
    install_exit_handlers()
