"""``radseek diagnose``: compare the measurement model with a flight, show where it fails, find the missing effect.

One job per module:

- ``features``: per-frame quantities to plot residuals against (rate, distance, bearing, wall path, time, x/y).
- ``residuals``: Pearson / deviance residuals, per-dwell aggregation, binned residual trends, deviance moments.
- ``dispersion``: the over-dispersion test on pairs of consecutive frames (robust to a wrong mean).
- ``selection``: forward selection over the effect vocabulary with likelihood-ratio tests (boundary-aware nulls).
- ``explain``: one-sentence physics per effect and the residual feature it should remove.
- ``plots``: matplotlib (Agg) PNGs.
- the text and JSON reports are ``reporting.diagnose_report`` (a layer that may see the truth: the source error).
- ``runner``: the whole loop (fit, compare, select, add) used by ``radseek_cli.diagnose_cli``.
"""
