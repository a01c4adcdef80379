"""Hardware-in-the-loop layer: one plant interface, the FMU or the real rig over serial."""
