"""The detector board emulator: world physics, detector response, comparator firmware, frame codec,
and the ``radseek detector`` process. It alone sees the true world (sources, true pose)."""
