"""radseek's I/O layer: the files of the contracts (:mod:`radseek`) read and written.

- :mod:`radseek_io.dataset`: a dataset directory's ``frames.csv`` and ``scenario.json`` (read, validate, write);
- :mod:`radseek_io.truth`: its ``truth.json`` (never imported by the flight software);
- :mod:`radseek_io.spectrum_io`: spectrum files (N42, SPE, CHN, CSV, RadiaCode, NDJSON);
- :mod:`radseek_io.detector_file`: the calibrated detector file;
- :mod:`radseek_io.mcap_log`, :mod:`radseek_io.mcap_frames`: MCAP flight logs, written and read back, with
  :mod:`radseek_io.mavlink_json` (MAVLink as JSON and its schemas), :mod:`radseek_io.foxglove_view` and
  :mod:`radseek_io.foxglove_schemas` (the flight in Foxglove's well-known schemas);
- :mod:`radseek_io.outdir`: output folders and atomic writes.

It imports only the contracts (tests/test_architecture.py).
"""
