"""The host side of the rig: what runs on the PC beside the link (bring-up, runs, records)."""
