"""Reports that score a search against the simulated truth: the one layer above the flight software allowed to
see ``Truth`` (with the launchers, benchmarks, tests and command-line tools).

- :mod:`reporting.truth_errors`: position and intensity errors of estimates against the truth;
- :mod:`reporting.diagnose_report`: the ``radseek diagnose`` report, text and JSON.

The command-line layer (:mod:`radseek_cli`) reads ``truth.json`` (:mod:`radseek_io.truth`) and hands the truth
to these functions; the flight packages never import them (tests/test_architecture.py).
"""
