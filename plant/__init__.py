"""Plant emulator core (docs/design.md section 5): pure and deterministic, time is an argument.

``plant.core.Plant`` ties together the thrust profile and valve timeline (``plant.thruster``,
seed 004 eq. 4.1), the rigid body (``plant.dynamics``), the flex modes (``plant.flex``, seed 003
eq. 2), the gyro (``plant.gyro``, seed 003 eq. 3 and seed 002) and the fault state
(``plant.faults``). ``hil.thruster_profile_cmd`` adds ``hil thruster-profile``.
"""
