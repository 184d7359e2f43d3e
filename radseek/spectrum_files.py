"""Compatibility name of :mod:`radseek.spectrum_io` (the spectrum readers, one module per format)."""

from radseek.spectrum_io import *  # noqa: F401,F403
from radseek.spectrum_io import __all__  # noqa: F401
