"""The mock autopilot (``radseek vehicle``), the MAVLink mission client, the mission state machine,
dwell-controller wiring and dataset recording. No physics or estimation maths lives here."""
