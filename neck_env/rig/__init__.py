"""The real rig: the host side of the Arduino UNO firmware, and its emulator.

* :mod:`neck_env.rig.protocol` -- frames, CRC, messages, streaming decoder (pure, no I/O);
* :mod:`neck_env.rig.link` -- the serial link (pyserial ports and URLs, replies by SEQ,
  timeouts, lease heartbeat, reconnect); :mod:`neck_env.rig.errors` -- what can go wrong;
* :mod:`neck_env.rig.hardware_env` -- ``HardwareNeckEnv``, NeckTrack-v0 on the rig;
* :mod:`neck_env.rig.thermal_estimate` -- spring temperatures from the commanded currents;
  :mod:`neck_env.rig.memory` -- that estimate carried across commands on a port;
* :mod:`neck_env.rig.pulse`, :mod:`neck_env.rig.session`, :mod:`neck_env.rig.cli` -- the step
  experiment, the diagnosis's recording protocol as a resumable session, and
  ``python -m neck_env.rig run | pulse | protocol | info | emulate``;
* the emulated rig (user-facing: ``rig emulate``; also the HIL tests'):
  :mod:`neck_env.rig.simavr` runs the real firmware build under simavr with a fake MPU6050,
  thermistor inputs and relay pins; :mod:`neck_env.rig.sim_neck` -- the simulator playing the
  neck in that loop, with catalogue effects (``EmulatedRig``: both, on a pty).

``HardwareNeckEnv`` applies the task's rules through ``neck_env.task.Task`` (the simulated
envs' task object); ``run`` finds controllers and policies through ``neck_env.agent`` (the
``neck_env.agents`` entry points), never by importing them.

Submodules are imported on demand so that importing the package stays free of
side effects (no subprocesses, no serial ports).
"""

__all__ = ["protocol", "link", "errors", "hardware_env", "thermal_estimate", "memory", "pulse",
           "session", "cli", "simavr", "sim_neck"]
