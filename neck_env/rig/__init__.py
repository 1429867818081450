"""The real rig: the Arduino UNO firmware's wire protocol and its simavr HIL harness.

* :mod:`neck_env.rig.protocol` -- frames, CRC, messages, streaming decoder (pure, no I/O);
* :mod:`neck_env.rig.simavr` -- runs the real firmware build under simavr with a fake
  MPU6050, thermistor inputs and relay pins (hardware in the loop).

Submodules are imported on demand so that importing the package stays free of
side effects (no subprocesses, no serial ports).
"""

__all__ = ["protocol", "simavr"]
