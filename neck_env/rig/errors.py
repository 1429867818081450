"""Exceptions of the rig host side. Every one means: the run stopped, relays were commanded off.

``RigError`` is the base for everything the hardware can do wrong; callers that want to retry
(after :meth:`neck_env.rig.link.RigLink.reconnect`, a fresh ``reset``) catch it. Ctrl-C is
reported as :class:`RigInterrupted`, a ``KeyboardInterrupt`` (so ``except Exception`` does not
swallow it), after the relays were commanded off.
"""

from __future__ import annotations

from . import protocol as P

__all__ = ["RigError", "RigLinkLost", "RigTimeout", "RigRefused", "RigImuError",
           "RigFirmwareReset", "RigNotAtRest", "RigInterrupted", "raise_for_faults", "fault_names"]


class RigError(RuntimeError):
    """Anything that stops the rig from running safely; the relays were commanded off."""


class RigLinkLost(RigError):
    """The serial port failed or vanished (USB unplugged, emulator gone)."""


class RigTimeout(RigError):
    """The firmware did not answer, or stopped streaming telemetry, in time."""


class RigRefused(RigError):
    """The firmware rejected a command (NAK) or answered with something unexpected."""


class RigImuError(RigError):
    """The MPU6050 is missing, answers with a foreign WHO_AM_I, or fails to read."""


class RigFirmwareReset(RigError):
    """The MCU restarted mid-run (watchdog, brown-out, reset button): commands were lost."""


class RigNotAtRest(RigError):
    """The neck did not come to rest (springs near ambient, tilt at its rest reading) in time."""


class RigInterrupted(KeyboardInterrupt):
    """Ctrl-C during a rig run; the relays were commanded off before this was raised."""


def fault_names(faults: int) -> list[str]:
    """Names of the set fault bits, e.g. ``['IMU_MISSING', 'SAFETY_TRIP']``."""
    return [f.name for f in P.Fault if faults & f]


_IMU_HELP = {
    P.Fault.IMU_MISSING: "no MPU6050 answers at I2C address 0x68: check its wiring "
                         "(SDA A4, SCL A5, VCC, GND) and that AD0 is low",
    P.Fault.IMU_BAD_ID: "the chip at 0x68 is not an MPU6050 (WHO_AM_I != 0x68)",
    P.Fault.IMU_READ: "the MPU6050 read failed or it lost its configuration (loose wire, "
                      "brown-out)",
}


def raise_for_faults(faults: int, where: str) -> None:
    """Raise :class:`RigImuError` if the fault word carries an IMU fault (the tilt would be
    meaningless); other faults are the firmware's safety holds and are reported, not raised."""
    for bit, help_text in _IMU_HELP.items():
        if faults & bit:
            raise RigImuError(f"{where}: IMU fault {bit.name}: {help_text} "
                              f"(all faults: {', '.join(fault_names(faults))})")
