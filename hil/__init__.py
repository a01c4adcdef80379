"""Hardware-in-the-loop layer: one plant interface, the FMU or the real rig over serial.

Rooms, each importing only the ones listed before it (tests/import_graph.py ROOMS): ``link``
(the protocol and the host's serial driver), ``host`` (plant back-ends, homing, experiments,
recording, response surfaces), ``emulators`` (the MCU model, the firmware's host build, QEMU,
the rehosted board), ``panel`` (the web front panel) and ``cli`` (the ``hil`` command).
"""
