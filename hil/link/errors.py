"""The errors of the rig link (docs/rig-protocol-behaviour.md, sections 7, 10 and 11).

Every failure a :class:`hil.link.serial_link.SerialLink` session can meet is a
:class:`RigError`, so callers (homing, bring-up, the back-ends, the panel) catch one base
and tell the kinds apart by class: no answer, a refusal, silence, a stall, a lost port, an
MCU reset, a latched fault.
"""

from __future__ import annotations

from hil.link import protocol as p


class RigError(Exception):
    """Base of every error of the rig link."""


class HandshakeError(RigError):
    """No session could be opened (no answer, wrong protocol version, rig busy)."""


class CommandError(RigError):
    """A command was refused (NAK) or never acknowledged."""


class LinkTimeoutError(RigError):
    """The host-side watchdog saw no telemetry for longer than its timeout."""


class RigStalledError(RigError):
    """The MCU's own timestamps show that it missed periods (its firmware stalled)."""


class LinkLostError(RigError):
    """The port failed or was disconnected."""


class RigResetError(RigError):
    """The MCU rebooted during the session; its position reference is lost."""


class RigFaultError(RigError):
    """The MCU latched a fault (it has already stopped or halted)."""

    def __init__(self, message: str, faults: p.Fault) -> None:
        super().__init__(message)
        self.faults = faults


