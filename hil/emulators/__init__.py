"""Rigs without hardware: the MCU model, the firmware's host build, QEMU and the rehosted board,
each behind a pseudo-terminal speaking the protocol, over the plant's physics."""
