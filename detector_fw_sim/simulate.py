"""Simulated flights in the dataset format, from the same physics as the board emulator.

``simulate_flight`` flies a path (flight_paths.py), takes 10 Hz frames (duration ~ N(0.1 s, 0.4 ms),
pose at the middle of each frame), draws the counts at the TRUE pose with ``DetectorEmulator``, and
records the pose as the vehicle would estimate it (shared/datasets/README.md): a per-segment offset
(sd 0.04 m horizontal, 0.015 m vertical; 0.05 m outdoors) plus 0.01 m (0.005 m vertical) jitter,
with var_x/var_y/var_z giving that variance, and, with ``pose_drift``, recorded = true + v * t.
scenario.json gets the operator's background estimate, a few % (sd 3 %) off the truth unless the
scene gives one. One seed fixes the whole dataset.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.flight_paths import FlightPath, build_trajectory, make_path
from detector_fw_sim.scene import Scene
from radseek.dataset import Dataset, Frames

FRAME_S = 0.1
FRAME_JITTER_S = 0.0004
JITTER_H_M, JITTER_V_M = 0.01, 0.005
OFFSET_V_M = 0.015
YAW_JITTER_RAD = 0.01
BACKGROUND_ESTIMATE_SD = 0.03


def simulate_flight(scene: Scene, path: str | Path | FlightPath = "lattice", seed: int = 0) -> Dataset:
    """Fly ``path`` through ``scene`` and return the dataset (frames, scenario, truth) in memory."""
    rng = np.random.default_rng(seed)
    flight = make_path(path, scene, rng)
    traj = build_trajectory(flight)
    n = int(traj.duration / FRAME_S)
    duration = np.clip(rng.normal(FRAME_S, FRAME_JITTER_S, n), 0.09, 0.11)
    t_end = np.cumsum(duration)
    keep = t_end <= traj.duration
    duration, t_end = duration[keep], t_end[keep]
    t_mid = t_end - duration / 2
    true_pose, dwell = traj.sample(t_mid)

    emulator = DetectorEmulator(scene, seed=int(rng.integers(2**63)))
    counts = emulator.draw_many(true_pose, t_mid, duration)

    # recorded pose: per-segment offset + per-frame jitter (+ drift)
    offset_h = 0.05 if scene.kind == "outdoor" else 0.04
    segment = np.searchsorted(traj.t1, t_mid, side="left")
    seg_off = np.column_stack([rng.normal(0, offset_h, (len(traj.t1), 2)), rng.normal(0, OFFSET_V_M, len(traj.t1))])
    jitter = np.column_stack([rng.normal(0, JITTER_H_M, (len(t_mid), 2)), rng.normal(0, JITTER_V_M, len(t_mid))])
    recorded = true_pose[:, :3] + seg_off[np.clip(segment, 0, len(traj.t1) - 1)] + jitter
    pd = scene.effects.pose_drift
    if pd.enabled:
        recorded[:, 0] += pd.vx * t_mid
        recorded[:, 1] += pd.vy * t_mid
    yaw = true_pose[:, 3] + rng.normal(0, YAW_JITTER_RAD, len(t_mid))
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
    var_h = offset_h**2 + JITTER_H_M**2
    var_v = OFFSET_V_M**2 + JITTER_V_M**2

    frames = Frames(
        t=t_end, duration=duration, x=recorded[:, 0], y=recorded[:, 1], z=recorded[:, 2], yaw=yaw,
        var_x=np.full(len(t_end), var_h), var_y=np.full(len(t_end), var_h), var_z=np.full(len(t_end), var_v),
        dwell=dwell.astype(int), counts=counts,
    )
    bg_estimate = scene.background.operator_estimate_cps
    if bg_estimate is None:
        bg_estimate = scene.background.cps * (1 + rng.normal(0, BACKGROUND_ESTIMATE_SD))
    scenario = scene.scenario(background_cps=max(bg_estimate, 0.0))
    return Dataset(frames=frames, scenario=scenario, truth=scene.truth())
