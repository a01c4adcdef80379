"""The host side of a run: the plant back-ends (FMU, rig), homing, experiments, recording, RSMs."""
