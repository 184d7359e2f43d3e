"""The comparator ladder of paper 003 (sec. II-A): 32 comparators against reference voltages from a
resistor ladder; a pulse of amplitude V is counted in the highest channel whose threshold it crosses.

Thresholds are voltages; the front-end gain (mV per keV) turns them into energy edges. Gain drift
scales the gain: at time t the gain is g0 * (1 + p/100 * t/60), so a deposited energy E produces
the amplitude of E * (1 + p t / 6000) at nominal gain, i.e. the edges in deposited energy shrink by
that factor while the comparator voltages stay put.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radseek.topics import N_CHANNELS

#: Edges of the reference board (shared/datasets): 40-1600 keV, slightly widening, plus 3000 keV
#: closing the overflow channel.
REFERENCE_EDGES_KEV = (
    40.0, 83.0, 126.5, 170.5, 215.0, 260.0, 305.4, 351.4, 397.8, 444.7, 492.1, 540.0, 588.4, 637.2, 686.6,
    736.4, 786.7, 837.5, 888.8, 940.6, 992.9, 1045.6, 1098.9, 1152.6, 1206.8, 1261.5, 1316.7, 1372.4, 1428.6,
    1485.2, 1542.4, 1600.0, 3000.0,
)


@dataclass(frozen=True)
class ComparatorLadder:
    """A resistor ladder from 0 V to ``v_ref_V``: tap k sits at v_ref * sum(R[:k+1]) / sum(R).

    ``resistors_ohm`` has 33 values: 32 taps for the comparators plus the top resistor; the last
    nominal edge (closing the overflow channel) is the ladder top. ``gain_mV_per_keV`` converts.
    """

    resistors_ohm: tuple[float, ...]
    v_ref_V: float = 3.3
    gain_mV_per_keV: float = 1.1

    def __post_init__(self) -> None:
        if len(self.resistors_ohm) != N_CHANNELS + 1:
            raise ValueError(f"resistors_ohm must have {N_CHANNELS + 1} values, got {len(self.resistors_ohm)}")
        if min(self.resistors_ohm) <= 0:
            raise ValueError("resistors_ohm must all be > 0")

    def tap_voltages_V(self) -> np.ndarray:
        """(33,) voltages: the 32 comparator thresholds and the ladder top."""
        r = np.asarray(self.resistors_ohm, dtype=float)
        return self.v_ref_V * np.cumsum(r) / r.sum()

    def thresholds_V(self) -> np.ndarray:
        return self.tap_voltages_V()[:N_CHANNELS]

    def edges_keV(self, gain_factor: float | np.ndarray = 1.0) -> np.ndarray:
        """Channel edges in deposited energy: (33,) or (..., 33) for an array of gain factors."""
        e = self.tap_voltages_V() * 1000.0 / self.gain_mV_per_keV
        g = np.asarray(gain_factor, dtype=float)
        return e / g[..., None] if g.ndim else e / float(g)

    @staticmethod
    def from_edges(edges_keV: np.ndarray | tuple[float, ...], v_ref_V: float = 3.3) -> ComparatorLadder:
        """The ladder (resistor values) that realises the given 33 edges with the top at v_ref."""
        e = np.asarray(edges_keV, dtype=float)
        if e.shape != (N_CHANNELS + 1,) or not np.all(np.diff(e) > 0) or e[0] <= 0:
            raise ValueError(f"channel edges must be {N_CHANNELS + 1} ascending positive energies")
        gain = v_ref_V * 1000.0 / e[-1]
        resistors = np.diff(np.r_[0.0, e]) * 10.0  # 10 ohm per keV of step: any scale gives the same taps
        return ComparatorLadder(tuple(float(r) for r in resistors), v_ref_V, gain)


def gain_factor(t: np.ndarray | float, percent_per_min: float) -> np.ndarray:
    """Gain relative to nominal at sim time t (s): 1 + p/100 * t/60."""
    return 1.0 + percent_per_min / 100.0 * np.asarray(t, dtype=float) / 60.0


def drifted_edges(edges_keV: np.ndarray, t: np.ndarray | float, percent_per_min: float) -> np.ndarray:
    """(N, 33) edges in deposited energy at times t: a deposit E lands as if it were E * gain."""
    g = np.atleast_1d(gain_factor(t, percent_per_min))
    return np.asarray(edges_keV, dtype=float)[None, :] / g[:, None]
