"""IMU simulator with per-sample truth, and the disturbance matrix run against the estimator.

- :mod:`~sins_align.sim.simulator`: Earth rate, gravity, sway (tones, presets, events such as
  a shove or a door slam), sensor errors, sample loss and stamp faults.
- :mod:`~sins_align.sim.trajectory`: moving vehicle (segments, waves, presets), sensor errors
  with scale factors and rotor vibration, GNSS velocity and position (latency, dropouts).
- :mod:`~sins_align.sim.honesty`: the disturbance matrix (cases, invariants, one table).
"""
from sins_align.sim.simulator import (SWAY_PRESETS, Event, ImuSimulator, RunsResult, SimResult,
                                      Stream, SwayProfile, Tone, combine, corrupt, door_slam,
                                      relevel, shove, simulate, simulate_runs, sway_profile,
                                      tone, with_events)

__all__ = ["SWAY_PRESETS", "Event", "ImuSimulator", "RunsResult", "SimResult", "Stream",
           "SwayProfile", "Tone", "combine", "corrupt", "door_slam", "relevel", "shove",
           "simulate", "simulate_runs", "sway_profile", "tone", "with_events"]
