"""Measurement model and physical effects, localizers, Cramér-Rao bound, run metrics and the
model-vs-measurement diagnosis. Pure numpy functions; never sees the true world."""
