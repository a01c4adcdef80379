"""A model of the TI ADS131M02 (datasheet SBAS890, 2-channel 24-bit delta-sigma ADC) as the
load cell's converter: its SPI frames, DRDY, the output CRC and the STATUS word.

Modelled: frames of 24-bit words while CS is low (response, CH0, CH1, CRC), the commands
NULL, RREG and WREG of one register, RESET; the response to a command in the next frame
(NULL: STATUS; RREG: the register; WREG: 0x4000 | address << 7 | count - 1; RESET: 0xFF22);
the registers ID, STATUS, MODE, CLOCK, GAIN; a conversion every OSR / (CLKIN / 2)
(256 us at OSR 1024 and 8 MHz) while CLKIN runs and SYNC/RESET is high; DRDY low from a
conversion until its frame is read; the output CRC (CRC-16-CCITT, initial value 0xFFFF,
over the words before it); STATUS's RESET (set at power-on until MODE.RESET is written 0),
WLENGTH, DRDY0/1. Channel 0 converts the load value the board sets (counts); channel 1
reads 0. Faults to inject: ``present`` False (MISO floats low), ``crc_errors`` (frames whose
CRC is corrupted), ``drdy_stuck`` (conversions stop), ``status_set`` (bits forced in
STATUS). Not modelled: the input CRC, LOCK/UNLOCK, STANDBY/WAKEUP, multi-register
reads/writes, 16- and 32-bit word lengths, the digital filter's settling (a new value is
converted at once), noise (the board adds the load cell's).
"""

from __future__ import annotations

from collections.abc import Callable

from hil.emulators.rehost.machine import UNITS_PER_S, UnsupportedAccessError

WORD = 3
FRAME_WORDS = 4
ID_ADS131M02 = 0x2200  # bits 11:8 CHANCNT = 2 (the low byte is reserved)
REG_ID, REG_STATUS, REG_MODE, REG_CLOCK, REG_GAIN = 0x00, 0x01, 0x02, 0x03, 0x04
MODE_RESET = 1 << 10
RESET_VALUES = {REG_ID: ID_ADS131M02, REG_STATUS: 0x0500, REG_MODE: 0x0510,
                REG_CLOCK: 0x030E, REG_GAIN: 0x0000}
OSR = {0: 128, 1: 256, 2: 512, 3: 1024, 4: 2048, 5: 4096, 6: 8192, 7: 16256}


def crc16_ccitt(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16-CCITT (polynomial 0x1021, MSB first), the ADS131M02's output CRC."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


class Ads131m02:
    """The converter; the board calls :meth:`select`, :meth:`exchange` (one SPI byte),
    :meth:`drdy_low` and sets :attr:`load_counts`; ``clkin_hz()`` says what CLKIN gets."""

    def __init__(self, now: Callable[[], int], clkin_hz: Callable[[], int]) -> None:
        self.now, self.clkin_hz = now, clkin_hz
        self.present = True
        self.crc_errors = 0  # frames still to corrupt
        self.drdy_stuck = False
        self.status_set = 0
        self.load_counts = 0
        self.frames = 0
        self.power_on()

    def power_on(self) -> None:
        self.regs = dict(RESET_VALUES)
        self.running_since: int | None = None
        self.read_index = -1  # index of the last conversion read
        self.response = 0xFF22  # the reset acknowledgement answers the first frame
        self.cs_low = False
        self.out = b""
        self.inp = bytearray()
        self.sync_high = True

    # conversions --------------------------------------------------------------------------

    def _period_units(self) -> int | None:
        hz = self.clkin_hz()
        if not hz:
            return None
        return OSR[self.regs[REG_CLOCK] >> 2 & 7] * 2 * UNITS_PER_S // hz

    def _latest(self) -> int:
        """Index of the latest conversion (-1: none yet)."""
        period = self._period_units()
        if period is None or self.drdy_stuck or not self.sync_high:
            self.running_since = None
            return -1
        if self.running_since is None:
            self.running_since = self.now()
            self.read_index = -1
        return (self.now() - self.running_since) // period - 1

    def drdy_low(self) -> bool:
        """The DRDY pin: low while a conversion is waiting to be read."""
        return self.present and self._latest() > self.read_index

    def set_sync(self, high: bool) -> None:
        """The SYNC/RESET pin (PB2): low for long resets the device (held low here)."""
        if not high and self.sync_high:
            self.power_on()
        self.sync_high = high

    # SPI ------------------------------------------------------------------------------------

    def select(self, low: bool) -> None:
        """The chip select (PB12) changed to ``low``."""
        if not self.present:
            return
        if low and not self.cs_low:
            self.cs_low = True
            self._start_frame()
        elif not low and self.cs_low:
            self.cs_low = False
            self._end_frame()

    def exchange(self, byte: int) -> int | None:
        """One byte in on DIN, the answer on DOUT (None: the bus floats, no device)."""
        if not self.cs_low or not self.present:
            return None
        i = len(self.inp)
        self.inp.append(byte)
        return self.out[i] if i < len(self.out) else 0

    def _word(self, value: int) -> bytes:
        return (value & 0xFFFFFF).to_bytes(WORD, "big")

    def _status(self, fresh: bool) -> int:
        status = (self.regs[REG_MODE] & MODE_RESET) | (self.regs[REG_MODE] & 0x300)
        status |= 0x3 if fresh else 0
        return status | self.status_set

    def _start_frame(self) -> None:
        latest = self._latest()
        fresh = latest > self.read_index
        if self.response is None:
            self.response = self._status(fresh)
        ch0 = self.load_counts if latest >= 0 else 0
        body = self._word(self.response << 8) + self._word(ch0) + self._word(0)
        crc = crc16_ccitt(body)
        if self.crc_errors > 0:
            crc ^= 0x0400
            self.crc_errors -= 1
        self.out = body + self._word(crc << 8)
        self.read_index = max(self.read_index, latest)
        self.inp = bytearray()

    def _end_frame(self) -> None:
        self.frames += 1
        data = bytes(self.inp)
        if len(data) < WORD:
            raise UnsupportedAccessError(f"ADS131M02: a frame of {len(data)} bytes")
        command = data[0] << 8 | data[1]
        self.response = None  # NULL: STATUS of the next frame
        if command == 0x0000:
            return
        if command == 0x0011:
            self.power_on()
            return
        kind, addr, count = command >> 13, command >> 7 & 0x3F, (command & 0x7F) + 1
        if kind not in (0b011, 0b101) or count != 1:
            raise UnsupportedAccessError(f"ADS131M02: command {command:#06x} is not modelled")
        if addr not in RESET_VALUES:
            raise UnsupportedAccessError(f"ADS131M02: register {addr:#x} is not modelled")
        if kind == 0b101:  # RREG
            self.response = self.regs[addr]
            return
        if len(data) < 2 * WORD:
            raise UnsupportedAccessError("ADS131M02: WREG without its data word")
        value = data[WORD] << 8 | data[WORD + 1]
        if addr in (REG_ID, REG_STATUS):
            raise UnsupportedAccessError(f"ADS131M02: WREG of read-only register {addr:#x}")
        if addr == REG_MODE and value & 0x300 != 0x100:
            raise UnsupportedAccessError("ADS131M02: word lengths other than 24 bits are "
                                         "not modelled")
        if addr == REG_MODE and value & 0x3000:
            raise UnsupportedAccessError("ADS131M02: the input and register-map CRC are "
                                         "not modelled")
        self.regs[addr] = value
        self.response = 0x4000 | addr << 7


__all__ = ["Ads131m02", "crc16_ccitt"]
