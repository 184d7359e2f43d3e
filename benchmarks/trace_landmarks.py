"""Trace one seeded flight dwell by dwell: where each dwell was, the odometry drift it was measured under (recorded
minus true pose), the drift-aware bound of the frames so far with and without the mapped walls as landmarks of the
drift (``estimator.localizers.mle.pose_aware_crlb(landmarks=False/True)``, at the true source), and the in-flight
estimate's error and 1-sigma after it (issue 36: does a dwell at a wall's shadow edge pin the drift?).

    python benchmarks/trace_landmarks.py lattice-wall lattice 0
    python benchmarks/trace_landmarks.py lattice-wall info 0
"""

from __future__ import annotations

import argparse
import math

import numpy as np


def trace(scene_name: str, strategy: str, seed: int) -> list[str]:
    """The trace's lines for one flight of ``launch.offline.fly_offline``."""
    from detector_fw_sim.scene import load_scene
    from estimator.inflight import bound_m
    from estimator.localizers.mle import MaximumLikelihood, pose_aware_crlb
    from launch.offline import fly_offline
    from mission.search import SearchConfig

    r = fly_offline(load_scene(scene_name), SearchConfig(strategy=strategy), seed=seed)
    src = r.dataset.truth.sources[0]
    frames = r.dataset.frames
    last = r.brain.estimates[-1]
    model = MaximumLikelihood(effects=tuple(last.effects or ())).model_for(r.dataset.scenario)
    theta = {"x": src.x, "y": src.y, "z": src.z, "cps_at_1m": src.cps_at_1m,
             "background_cps": r.dataset.scenario.background_cps}
    theta.update({k: float(v) for k, v in (last.params or {}).items()})
    theta = {k: v for k, v in theta.items() if k in model.param_names}
    ix, iy = model.free_names.index("x"), model.free_names.index("y")
    dwell = np.asarray(frames.dwell)
    drift = np.column_stack([frames.x, frames.y]) - r.true_path[:, :2]
    after = {e.dwell: e for e in r.brain.estimates}
    cov = np.asarray(last.covariance, dtype=float)[:2, :2]
    miss = np.array([last.x - src.x, last.y - src.y])
    d2 = float(miss @ np.linalg.pinv(cov) @ miss) if np.isfinite(cov).all() else math.nan
    w, v = np.linalg.eigh(cov) if np.isfinite(cov).all() else (np.full(2, math.nan), np.eye(2))
    along = np.abs(v.T @ miss)  # the miss along the ellipse's minor and major axes
    out = [f"{scene_name} {strategy} seed {seed}: mission {r.mission_time_s:.0f} s, final error "
           f"{math.hypot(last.x - src.x, last.y - src.y):.3f} m, effects {list(model.effects)}, "
           f"stop: {r.decisions[-1].reason}",
           f"  final ellipse: 1-sigma axes {math.sqrt(max(w[1], 0)):.3f} / {math.sqrt(max(w[0], 0)):.3f} m, miss along "
           f"them {along[1]:.3f} / {along[0]:.3f} m, Mahalanobis d2 {d2:.1f} (95 % holds it below 5.99), "
           f"fit p {last.p_value:.2g}, misfit factor {last.extra.get('misfit_factor')}, "
           f"other mode {last.extra.get('other_mode')}, params {dict(last.params)}"]
    for k in np.unique(dwell[dwell >= 0]):
        upto = frames.select(np.arange(len(frames.t)) <= np.flatnonzero(dwell == k).max())
        bounds = [bound_m(pose_aware_crlb(model, theta, upto, landmarks=lm)[np.ix_([ix, iy], [ix, iy])])
                  for lm in (False, True)]
        m = dwell == k
        p = np.column_stack([frames.x, frames.y])[m].mean(0)
        e = after.get(int(k) + 1)
        est = f"  error {math.hypot(e.x - src.x, e.y - src.y):.3f} 1-sigma {e.sigma_m:.3f}" if e else ""
        out.append(f"  dwell {k:2d} at ({p[0]:.2f}, {p[1]:.2f}) r {math.hypot(p[0] - src.x, p[1] - src.y):.2f} m, "
                   f"drift ({drift[m, 0].mean():+.3f}, {drift[m, 1].mean():+.3f}) m, bound {bounds[0]:.3f} m, "
                   f"landmark bound {bounds[1]:.3f} m{est}")
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene")
    p.add_argument("strategy")
    p.add_argument("seed", type=int)
    args = p.parse_args(argv)
    print("\n".join(trace(args.scene, args.strategy, args.seed)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
