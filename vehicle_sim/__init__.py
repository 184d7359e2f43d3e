"""The mock autopilot: a SITL-style multicopter speaking MAVLink 2 over UDP (``radseek vehicle``).

Pure parts (``frames``, ``motion``, ``odometry``, ``battery``, ``failsafe``) take arrays and numbers
and return new ones; ``mission_protocol``, ``commands`` and ``navigator`` are state machines driven by
messages and the sim clock; ``link`` (sockets) and ``vehicle`` (the loop) are the edges.
"""
