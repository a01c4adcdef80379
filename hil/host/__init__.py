"""The host side of the rig: what runs on the PC beside the link (plant back-ends, homing,
experiments, recording, response surfaces, bring-up)."""
