"""One board frame measured at a true pose: the detector's physics step, shared by the detector process
(which publishes it over zenoh) and the in-process world (``vehicle_sim.world``, which hands it over).

Frame ``k`` integrates ``[k T, (k+1) T)`` (``detector_fw_sim.board``) at the true pose of its mid-time.
Without a true pose the board sends zero counts flagged ``STALE_POSE`` (the emulator invents nothing);
a pose the physics cannot evaluate is reported the same way. Counts above the u16 field are clamped and
flagged (``Board.make_frame``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from detector_fw_sim import transport
from detector_fw_sim.board import Board
from radseek import topics
from radseek.board_wire import Frame

if TYPE_CHECKING:
    from detector_fw_sim.scene import Scene


class CountSource(Protocol):
    """What a readout needs from ``detector_fw_sim.emulator.DetectorEmulator``."""

    scene: Scene

    def draw(self, pose: np.ndarray, t: float, duration: float) -> np.ndarray:
        """(32,) counts for true pose (x, y, z, yaw), frame mid-time ``t`` and ``duration`` (s)."""
        ...

    def true_rates(self, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(N, 32) true rates before dead time, cps."""
        ...


def live_time(emulator: CountSource, pose: np.ndarray, t_mid: float, duration: float) -> float:
    """Emulator truth for diagnostics: the live part of ``duration``.

    With paralyzable dead time (paper 000 eq. 10) the recorded/true ratio exp(-n tau), n the total true
    rate, is the live fraction; without the dead-time effect the whole interval is live.
    """
    dt = emulator.scene.effects.dead_time
    if not dt.enabled:
        return float(duration)
    n = float(np.sum(emulator.true_rates(np.asarray(pose, dtype=float)[None, :], np.array([t_mid]))))
    return float(duration * transport.dead_time(n, dt.tau_s))


@dataclass(frozen=True)
class Readout:
    """Frame ``k`` as the board built it, the emulator's live time (None without counts), and the state the
    detector reports (``ok``, ``stale_pose``, ``emulator_error``; ``error`` says why for the last)."""

    frame: Frame
    live_time: float | None
    state: str
    error: str | None = None


def read_out(board: Board, emulator: CountSource, k: int, pose: np.ndarray | None) -> Readout:
    """Measure frame ``k`` at true ``pose`` (x, y, z, yaw) of its mid-time, or send a stale frame (None)."""
    t0, t1 = board.interval(k)
    if pose is None:
        return Readout(board.make_frame(k, np.zeros(topics.N_CHANNELS, dtype=np.int64), stale_pose=True), None,
                       "stale_pose")
    t_mid = 0.5 * (t0 + t1)
    try:
        counts = np.asarray(emulator.draw(pose, t_mid, board.period_s))
        live = live_time(emulator, pose, t_mid, board.period_s)
    except ValueError as exc:  # an absurd pose the physics cannot evaluate: report, send no data
        return Readout(board.make_frame(k, np.zeros(topics.N_CHANNELS, dtype=np.int64), stale_pose=True), None,
                       "emulator_error", str(exc))
    return Readout(board.make_frame(k, counts), live, "ok")


def true_pose_for(latest: topics.TruthPose | None, at, t0: float, t1: float, stale_after_s: float) -> np.ndarray | None:
    """The true pose (x, y, z, yaw) at the mid-time of ``[t0, t1)``, interpolated by ``at(t, max_gap_s)`` from
    the true poses received; None (a stale frame) when the ``latest`` is older than ``stale_after_s``."""
    if latest is None or t1 - latest.t > stale_after_s:
        return None
    msg = at(0.5 * (t0 + t1), stale_after_s)
    return None if msg is None else np.array([msg.x, msg.y, msg.z, msg.yaw])
