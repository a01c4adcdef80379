"""The ``hil`` command line (main.py) with its ``rig`` and ``rsm`` commands and signal handling."""

from hil.cli.interrupts import install_exit_handlers, started_as_hil

# the `hil` command (its console script or `python -m hil.cli`) gets its SIGINT/SIGTERM
# handlers here, before hil.cli.main's heavy imports: a Ctrl-C in the first second of `hil run`
# printed a KeyboardInterrupt traceback, and a SIGTERM killed it without its exit code 143
if started_as_hil():
    install_exit_handlers()
