"""Dwell points and mission time to reach 0.3 m error: eq. 6 planner vs baselines, over seeded scenes.

THE HOOK. ``run_episode`` flies one strategy with two callables it does not implement:

* ``measure(point (3,), yaw) -> (rate_cps, dwell_s)``: hover and count until the dwell controller
  stops (the simulator's job: ``detector_fw_sim`` frames fed to ``planner.dwell_controller``);
* ``localize(history) -> SourceBelief | None``: the estimator's job (``estimator``).

The truth is used only here, by ``error_fn``, to decide when 0.3 m is reached. By default the real
parts fly it: ``measure`` draws 10 Hz frames from ``detector_fw_sim``'s emulator at the dwell pose and
feeds them to the dwell controller; ``localize`` is the estimator's Poisson MLE (``estimator.mle``) on
the dwells so far. ``--stand-in`` keeps the original smoke-test stand-ins (inverse-square Poisson
frames, a least-squares fit).

Run: ``.venv/bin/python benchmarks/planner_vs_baselines.py [--seeds 10] [--stand-in]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from planner import baselines as bl
from planner.belief import DwellHistory, SourceBelief
from planner.dwell_controller import DwellController
from planner.dwell_tree import seed_ompl
from planner.exploration import FrontierConfig, exploration_done, plan_exploration
from planner.next_best import NextBestConfig, plan_next_dwell
from planner.occupancy import OccupancyMap

Measure = Callable[[np.ndarray, float], tuple[float, float]]
Localize = Callable[[DwellHistory], SourceBelief | None]


@dataclass
class Episode:
    strategy: str
    dwells: int = 0  # dwell points flown
    mission_time: float = 0.0  # s, dwell + transit at the planner speed
    errors: list[float] = field(default_factory=list)  # m, after each dwell (nan before an estimate)
    reached: bool = False
    stop: str = ""  # why it ended: "target", "max_dwells", "no plan"


def run_episode(strategy: str, occ: OccupancyMap, start: np.ndarray, background: float, measure: Measure,
                localize: Localize, error_fn: Callable[[SourceBelief], float], rng: np.random.Generator,
                target_m: float = 0.3, max_dwells: int = 25, speed: float = 0.5, pre_threshold: float = 150.0
                ) -> Episode:
    """Fly ``strategy`` (next-best, greedy, lattice, lawnmower, spiral, pre) until the error is below target.

    Every measurement is a dwell point, including PRE's eight neighbour readings per step."""
    ep = Episode(strategy)
    current = np.asarray(start, dtype=float).copy()
    history = DwellHistory()
    visited: list[np.ndarray] = [current[None, :3]]
    z = float(current[2])
    queue: list[np.ndarray] = []
    if strategy == "lattice":
        centre = np.r_[(occ.free_min[:2] + occ.free_max[:2]) / 2, z]
        queue = list(bl.valid_points(bl.fixed_lattice(centre, float(np.min(occ.free_max[:2] - occ.free_min[:2])) / 3),
                                     occ))
    elif strategy == "lawnmower":
        queue = list(bl.valid_points(bl.lawnmower(occ.bounds_min, occ.bounds_max, 2.0, z, margin=1.0), occ))
    elif strategy == "spiral":
        centre = np.r_[(occ.free_min[:2] + occ.free_max[:2]) / 2, z]
        queue = list(bl.valid_points(bl.spiral(centre, 1.5, occ.free_min, occ.free_max), occ))
    pre = pre_points(current[:3], occ, bl.PREGradient(threshold=pre_threshold), rng) if strategy == "pre" else None
    last_rate: float | None = None
    belief = None
    while ep.dwells < max_dwells:
        path = None
        if pre is not None:
            try:
                p = next(pre) if last_rate is None else pre.send(last_rate)
            except StopIteration:
                p = None
            point = None if p is None else np.r_[p, current[3]]
        elif strategy in ("next-best", "greedy"):
            if belief is None or not exploration_done(history, background):
                plan = plan_exploration(current, history, occ, np.concatenate(visited), FrontierConfig(), rng=rng)
                point, path = (plan.dwell_points[0], plan.path) if plan.ok else (None, None)
            elif strategy == "next-best":
                plan = plan_next_dwell(current, belief, history, occ, NextBestConfig(), rng=rng)
                if not plan.ok:  # every node rejected (e.g. a huge covariance): explore instead
                    plan = plan_exploration(current, history, occ, np.concatenate(visited), FrontierConfig(), rng=rng)
                point, path = (plan.dwell_points[0], plan.path) if plan.ok else (None, None)
            else:
                p, _ = bl.greedy_info_gain(current[:3], belief, occ, rng=rng)
                point = np.r_[p, current[3]]
        else:
            point = np.r_[queue.pop(0), current[3]] if queue else None
        if point is None:
            ep.stop = "no plan"
            break
        if path is None:
            path = np.vstack([current, point])
        ep.mission_time += float(np.linalg.norm(np.diff(path[:, :3], axis=0), axis=1).sum()) / speed
        visited.append(path[:, :3])
        rate, dwell_s = measure(point[:3], float(point[3]))
        last_rate = rate
        ep.mission_time += dwell_s
        ep.dwells += 1
        history = DwellHistory(np.vstack([history.positions, point[None, :3]]), np.r_[history.rates, rate])
        current = point
        belief = localize(history)
        err = error_fn(belief) if belief is not None else float("nan")
        ep.errors.append(err)
        if err < target_m:
            ep.reached, ep.stop = True, "target"
            break
    ep.stop = ep.stop or "max_dwells"
    return ep


def pre_points(start: np.ndarray, occ: OccupancyMap, policy: bl.PREGradient, rng: np.random.Generator):
    """Paper 001 Algorithm 1 as a generator: yields each point to measure and receives its rate (send).

    A step measures the 8 valid neighbours one ``policy.step`` away (eq. 1 needs their readings; invalid
    neighbours count as -inf) and moves to one of them, whose reading becomes the next y_i; it ends when
    the circling closes a loop.
    """
    here = np.asarray(start, dtype=float)
    track = [here]
    y = yield here
    while True:
        nbrs = here + policy.step * np.c_[bl.UNIT_DIRECTIONS, np.zeros(8)]
        ok = occ.segments_valid(np.broadcast_to(here, nbrs.shape), nbrs)
        if not ok.any():
            return
        rates = np.full(8, -np.inf)
        for k in np.flatnonzero(ok):
            rates[k] = yield nbrs[k]
        here = policy.step_from(here, y, rates, rng)
        y = float(rates[int(np.argmin(np.linalg.norm(nbrs - here, axis=1)))])  # measured already: reuse it
        track.append(here)
        if not policy.rid_flag and bl.path_closed(np.array(track)):
            return


# ------------------------------------------------------------------ stand-ins (until the real ones exist)


def stand_in_measure(source: np.ndarray, cps_at_1m: float, background: float, rng: np.random.Generator) -> Measure:
    """Inverse-square + background Poisson frames at 10 Hz through the real dwell controller."""

    def measure(point: np.ndarray, yaw: float) -> tuple[float, float]:
        lam = cps_at_1m / max(float(((point - source) ** 2).sum()), 0.01) + background
        c = DwellController()
        t = 0.0
        while True:
            t += 0.1
            st = c.update(t, int(rng.poisson(lam * 0.1)), 0.1)
            if st.done:
                return st.mean_rate, st.live_time

    return measure


def stand_in_localize(source_z: float, background: float, lo: np.ndarray, hi: np.ndarray) -> Localize:
    """Least-squares inverse-square fit of (x, y, cps_at_1m), z fixed; covariance from the Jacobian."""

    def localize(h: DwellHistory) -> SourceBelief | None:
        if len(h) < 3:
            return None
        net = np.maximum(h.rates - background, 1e-3)
        sigma = np.sqrt(np.maximum(h.rates, 1.0) / 5.0)

        def resid(v: np.ndarray) -> np.ndarray:
            r2 = (h.positions[:, 0] - v[0]) ** 2 + (h.positions[:, 1] - v[1]) ** 2 + (h.positions[:, 2] - source_z) ** 2
            return (np.exp(v[2]) / np.maximum(r2, 1e-2) - net) / sigma

        best = None
        for k in np.argsort(-net)[:3]:  # starts near the strongest readings
            x0 = np.r_[h.positions[k, :2], np.log(max(net[k], 1.0))]
            fit = least_squares(resid, x0, bounds=(np.r_[lo[:2], -5], np.r_[hi[:2], 15]))
            if best is None or fit.cost < best.cost:
                best = fit
        assert best is not None
        jtj = best.jac.T @ best.jac
        cov2 = np.linalg.pinv(jtj)[:2, :2]
        cov = np.diag([0.0, 0.0, 1e-4])
        cov[:2, :2] = (cov2 + cov2.T) / 2 + np.eye(2) * 1e-4
        return SourceBelief(np.r_[best.x[:2], source_z], cov, float(np.exp(best.x[2])), background)

    return localize


# ------------------------------------------------------------------ the real simulator and estimator


def emulator_measure(source: np.ndarray, cps_at_1m: float, background: float, seed: int,
                     durations: list[float]) -> Measure:
    """10 Hz frames from the detector emulator (default scene, source moved to ``source``) at the dwell
    pose, through the real dwell controller; each dwell's live time is appended to ``durations``."""
    from detector_fw_sim.emulator import DetectorEmulator
    from detector_fw_sim.scene import load_scene

    scene = load_scene()
    data = scene.model_dump()
    data["sources"][0].update(position=[float(v) for v in source], cps_at_1m=cps_at_1m)
    data["background"]["cps"] = background
    em = DetectorEmulator(type(scene).model_validate(data), seed=seed)
    clock = [0.0]

    def measure(point: np.ndarray, yaw: float) -> tuple[float, float]:
        c = DwellController()
        pose = np.r_[point[:3], yaw]
        while True:
            clock[0] += 0.1
            st = c.update(clock[0], int(em.draw(pose, clock[0] - 0.05, 0.1).sum()), 0.1)
            if st.done:
                durations.append(st.live_time)
                return st.mean_rate, st.live_time

    return measure


def mle_localize(scenario, durations: list[float]) -> Localize:
    """Poisson MLE (estimator.mle, baseline model) on the dwells so far, one row per dwell."""
    from estimator.mle import fit
    from estimator.model import MeasurementModel
    from radseek.dataset import Frames

    model = MeasurementModel(scenario)

    def localize(h: DwellHistory) -> SourceBelief | None:
        if len(h) < 3:
            return None
        dur = np.asarray(durations[: len(h)])
        rows = np.zeros((len(h), 42))
        rows[:, 0] = np.cumsum(dur)
        rows[:, 1] = dur
        rows[:, 2:5] = h.positions
        rows[:, 9] = np.arange(len(h))
        rows[:, 10] = np.round(h.rates * dur)
        r = fit(model, Frames.from_rows(rows), n_starts=3, pose_uncertainty=False)
        i = [r.free_names.index("x"), r.free_names.index("y")]
        cov = np.diag([0.0, 0.0, 1e-6])
        c2 = r.covariance[np.ix_(i, i)]
        cov[:2, :2] = (c2 + c2.T) / 2 if np.all(np.isfinite(c2)) else np.eye(2)
        return SourceBelief(np.array([r.values["x"], r.values["y"], r.values["z"]]), cov,
                            max(r.values["cps_at_1m"], 1e-3), r.values["background_cps"])

    return localize


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--stand-in", action="store_true", help="use the stand-in measure/localize (smoke test)")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--quick", action="store_true", help="3 seeds")
    ap.add_argument("--cps", type=float, default=300.0, help="source net cps at 1 m (background 30 cps)")
    args = ap.parse_args()
    if args.quick:
        args.seeds = 3
    seed_ompl(11)
    lo, hi = np.array([0.0, 0.0, 0.5]), np.array([10.0, 8.0, 2.5])
    occ = OccupancyMap(lo, hi, (), 0.3)
    strategies = ("next-best", "greedy", "lattice", "lawnmower", "spiral", "pre")
    rows: dict[str, list[Episode]] = {s: [] for s in strategies}
    for seed in range(args.seeds):
        srng = np.random.default_rng(1000 + seed)
        source = np.r_[srng.uniform([2.0, 2.0], [8.0, 6.0]), 0.0]
        cps, bg = args.cps, 30.0
        for s in strategies:
            rng = np.random.default_rng(seed)
            if args.stand_in:
                measure, localize = stand_in_measure(source, cps, bg, rng), stand_in_localize(0.0, bg, lo, hi)
            else:
                from detector_fw_sim.scene import load_scene

                durations: list[float] = []
                measure = emulator_measure(source, cps, bg, seed, durations)
                localize = mle_localize(load_scene().scenario(background_cps=bg), durations)
            ep = run_episode(s, occ, np.array([0.6, 0.6, 1.5, 0.0]), bg, measure, localize,
                             lambda b, src=source: float(np.linalg.norm(b.mean[:2] - src[:2])), rng)
            rows[s].append(ep)
    label = "stand-ins" if args.stand_in else "emulator + MLE"
    print(f"{'strategy':<10} {'reached':>8} {'dwells (median)':>16} {'mission s (median)':>19}  ({label})")
    for s, eps in rows.items():
        ok = [e for e in eps if e.reached]
        dw = np.median([e.dwells for e in ok]) if ok else float("nan")
        tm = np.median([e.mission_time for e in ok]) if ok else float("nan")
        fails = ", ".join(sorted({e.stop for e in eps if not e.reached}))
        print(f"{s:<10} {len(ok):>4}/{len(eps):<3} {dw:>16.1f} {tm:>19.0f}  {fails}")


if __name__ == "__main__":
    main()
