"""The wire, host side: the rig protocol (framing, messages), the serial driver and its timing."""
