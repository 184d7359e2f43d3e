"""The setting of paper 003 Fig. 4: eq. 6 evaluated on a 3 x 3 m grid of candidates.

Fig. 4: "a 3x3 m grid with equally-spaced dwell candidates ... evaluated given the current source
location and three previous dwell points ..., while delta = 1 and zeta = 1.85". The paper does not give
the coordinates; ours put the source at the centre and the three previous dwell points in three
corners' neighbourhood, all in one horizontal plane (the figure is a surface over x, y).
"""

from __future__ import annotations

import numpy as np

from planner.gain import GainConfig, gain_eq6

FIG4_GAIN = GainConfig(delta=1.0, zeta=1.85)
FIG4_SOURCE = np.array([1.5, 1.5, 0.0])
FIG4_DWELLS = np.array([[0.3, 0.4, 0.0], [2.6, 0.5, 0.0], [0.4, 2.5, 0.0]])


def fig4_grid(n: int = 31) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """xs (n,), ys (n,), gain (n, n) indexed [iy, ix], and the best candidate (3,) of the grid."""
    xs = np.linspace(0.0, 3.0, n)
    ys = np.linspace(0.0, 3.0, n)
    gx, gy = np.meshgrid(xs, ys)
    nodes = np.stack([gx, gy, np.zeros_like(gx)], axis=-1)
    g = gain_eq6(nodes, FIG4_SOURCE, FIG4_DWELLS, FIG4_GAIN)
    iy, ix = np.unravel_index(int(np.argmax(g)), g.shape)
    return xs, ys, g, nodes[iy, ix]
