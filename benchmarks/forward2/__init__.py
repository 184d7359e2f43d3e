"""A second, independent forward model of a radseek flight (issue 14), for testing ``radseek diagnose`` on data
it was not built from.

Its own code path: it imports neither ``detector_fw_sim`` (the emulator) nor ``estimator`` (the model diagnose
fits), nor ``radseek.count_model`` / ``radseek.geometry``. It uses ``radseek.dataset`` only for the output
container (the dataset format) and ``radseek_io.spectrum_io`` to read measured spectra.

- spectra (``spectra.py``): measured CsI(Tl) spectra (``shared/real-spectra``: a RadiaCode-102's Cs-137, Co-60,
  Eu-152, Ba-133 and room background, background-subtracted by live time), altered crystals (worse resolution,
  more multiple-scatter fill, a stronger backscatter bump), or analytic crystals (``analytic-a``/``-b``: pydecay
  lines, Gaussian peaks with FWHM ~ sqrt(E), Klein-Nishina continuum, backscatter bump), rebinned onto the
  comparator edges at each frame's gain;
- flights (``paths.py``): lattice, spin, lawnmower, close-pass and outdoor survey paths, own kinematics;
- physics (``physics.py``): inverse square, walls (own slab clipping), air, a back cone, background gradient,
  event-by-event paralyzable dead time, gain drift on the fine spectrum, odometry drift and pose noise
  (independent per segment, or a random walk in distance flown), and frame-to-frame over-dispersion; for
  issue 30 also unmapped walls (``unmapped_wall``, ``random_unmapped_wall``, ``FlightSpec.unmap_walls``),
  second sources and primaries of other nuclides, and physics diagnose has no name for (``moving_source``,
  ``background_drift``).

``simulate(FlightSpec(...), seed)`` returns a ``radseek.dataset.Dataset`` in memory.
"""

from benchmarks.forward2.physics import FlightSpec, random_unmapped_wall, simulate

__all__ = ["FlightSpec", "random_unmapped_wall", "simulate"]
