"""The team's search decisions (paper 004's multi-robot search on paper 003's brain), with no I/O.

One :class:`TeamBrain` serves N vehicles. It keeps one dwell history, one explored area and one in-flight
estimate for the team: every vehicle's frames (:func:`team_frames`, each vehicle's odometry a random walk
of its own in the fit, ``estimator.mle.PoseGroups``) give one joint estimate after every dwell any vehicle
ends, and the stop rules of :class:`mission.search.SearchBrain` (sigma below ``stop_sigma_m``, stable,
fitting, or drift-limited; the dwell budget) apply to the team's dwells. Allocation, asked per vehicle when
its dwell ends:

* explore: paper 004's frontier exploration with area pruning: the cells near a teammate's reservation
  (its path and dwell point) count as visited, so each vehicle takes another frontier (eq. 4.1-4.2);
* search: the next-best dwell point of paper 003 eq. 6 with the teammates' pending dwell points counted as
  dwell points already taken (the gain's repulsion spreads the team), greedily the best node whose path
  keeps ``separation_m`` from every teammate's reservation (``planner.allocation``);
* if no path is free, the vehicle holds ``hold_s`` where it is and asks again (:meth:`TeamBrain.replan`).

The separation is kept between *true* positions: the vehicles fly on drifting estimates, so the clearance
asked of two estimated positions is ``separation_m`` plus ``planner.allocation.DRIFT_K`` times the standard
deviation of the difference of their drifts (each vehicle's reported x-y pose variance at the end of its
path: :meth:`TeamBrain.set_pose_variance`, the teammates' in their ``Reservation``).

A vehicle that fails (link loss, battery, its mission process killed) just stops asking; its last
reservation stays reserved, and the others finish the search.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from estimator.mle import walk_starts
from mission.search import Decision, Phase, SearchBrain, SearchConfig, belief_of
from planner.allocation import Reservation, as_reservation, clearance, path_clear, required_clearance, sample_polyline
from planner.belief import DwellHistory, SourceBelief, drift_density_from_poses
from planner.dwell_controller import DwellController, DwellStatus
from planner.dwell_tree import grow_tree, seed_ompl, shortcut_path
from planner.exploration import exploration_done, plan_exploration
from planner.next_best import finish_path, score_nodes
from planner.plan import DwellPlan
from radseek import topics
from radseek.dataset import Frames, Scenario
from radseek.outcome import Outcome

MAX_VEHICLES = 4
#: candidate dwell points tried, best gain first, before a vehicle holds
MAX_CANDIDATES = 40
#: holds in a row before a boxed-in vehicle retires from the search (the others go on)
MAX_HOLDS_IN_ROW = 30


@dataclass(frozen=True)
class TeamConfig:
    """Team settings (units in comments)."""

    n_vehicles: int = 2  # 1 .. MAX_VEHICLES
    separation_m: float = 1.0  # m, > 0: x-y clearance kept from every teammate's reservation
    hold_s: float = 2.0  # s, > 0: hover this long when no free path exists, then plan again
    home_spacing_m: float = 1.5  # m: launch points along +x from the first (>= separation_m)

    def __post_init__(self) -> None:
        if not 1 <= self.n_vehicles <= MAX_VEHICLES:
            raise ValueError(f"n_vehicles must be in 1..{MAX_VEHICLES}, got {self.n_vehicles}")
        if not (self.separation_m > 0 and self.hold_s > 0):
            raise ValueError("separation_m and hold_s must be > 0")
        if self.home_spacing_m < self.separation_m:
            raise ValueError("home_spacing_m must be >= separation_m (vehicles take off apart)")


def home_positions(scenario: Scenario, team: TeamConfig) -> np.ndarray:
    """(N, 2) launch points: the single vehicle's (0.5 m inside the bounds' lower corner), the others
    ``home_spacing_m`` apart along +x."""
    lo = np.asarray(scenario.bounds_min, dtype=float)
    return np.array([[lo[0] + 0.5 + i * team.home_spacing_m, lo[1] + 0.5] for i in range(team.n_vehicles)])


def team_dwell(dwell: np.ndarray, vehicle: int, n_vehicles: int) -> np.ndarray:
    """A vehicle's own dwell indices as team-unique ones (k -> k N + v; transit stays -1)."""
    d = np.asarray(dwell)
    return np.where(d >= 0, d * n_vehicles + vehicle, d)


def team_frames(per_vehicle: Sequence[Frames | None]) -> Frames:
    """The team's frames: each vehicle's frames (own time order, own dwell indices) concatenated vehicle by
    vehicle with team-unique dwell indices (:func:`team_dwell`), each frame's ``vehicle`` and its odometry
    ``walk`` (one per vehicle) said in their columns. Longest flight first, so that files written from it
    without those columns still read back with the walks apart (``Frames.walk``)."""
    n = len(per_vehicle)
    parts = [(v, f) for v, f in enumerate(per_vehicle) if f is not None and len(f)]
    if not parts:
        return Frames.from_records([])
    # order so that every vehicle starts before the previous one ended: longest flight first
    parts.sort(key=lambda vf: (-float(vf[1].t[-1]), vf[0]))
    names = list(Frames.__dataclass_fields__)
    cols = {k: np.concatenate([getattr(f, k) for _, f in parts]) for k in names}
    cols["dwell"] = np.concatenate([team_dwell(f.dwell, v, n) for v, f in parts]).astype(int)
    cols["vehicle"] = np.concatenate([np.full(len(f), v) for v, f in parts])
    cols["walk"] = cols["vehicle"].copy()  # one odometry walk per vehicle
    return Frames(**cols)


def split_walks(frames: Frames) -> list[Frames]:
    """The inverse of :func:`team_frames` for the fit's purposes: one Frames per odometry walk."""
    starts = np.flatnonzero(walk_starts(frames))
    bounds = np.r_[starts, len(frames)]
    return [frames.select(np.arange(a, b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]


@dataclass(frozen=True)
class TeamDecision(Decision):
    """What one vehicle does next (a ``Decision`` with its ``vehicle``): fly ``plan`` then dwell; or hover
    ``hold_s`` and ask again (:meth:`TeamBrain.replan`); or, neither, the team's search is over (``outcome``
    the team's search's end; ``retired``: this vehicle's)."""

    vehicle: int = 0
    hold_s: float = 0.0
    retire: bool = False  # this vehicle leaves the search (no free path for long); the team's goes on

    @property
    def done(self) -> bool:
        """The team's search is over (``retire``: this vehicle's part is)."""
        return self.plan is None and self.hold_s <= 0 and not self.retire

    def as_decision(self) -> Decision:
        return Decision(self.phase, self.plan, self.reason, self.outcome)


class TeamBrain(SearchBrain):
    """The joint brain: :class:`mission.search.SearchBrain`'s estimate and stop rules over the whole team's
    dwells, with per-vehicle dwell control and allocation under the teammates' reservations."""

    def __init__(self, scenario: Scenario, config: SearchConfig | None = None, team: TeamConfig | None = None,
                 seed: int = 0):
        super().__init__(scenario, config, seed)
        if self.config.strategy != "active":
            raise ValueError("a team flies the active search only")
        self.team = team or TeamConfig()
        self.dwells = [DwellController(self.config.dwell) for _ in range(self.team.n_vehicles)]
        self.dwelled_by: list[int] = []  # the vehicle of each dwell of ``history``
        self.search_dwelled_by: list[int] = []  # the vehicle of each search dwell (those ``search_dwells`` counts)
        self.holds = 0
        self._belief: SourceBelief | None = None
        self._in_row = [0] * self.team.n_vehicles  # holds in a row, per vehicle
        self._pose_var = np.zeros((self.team.n_vehicles, 2))  # per vehicle: x-y variance now (m^2), growth (m^2/m)
        self._sigma = math.inf
        self.final: TeamDecision | None = None
        # OMPL's random trees restart from this brain's own seed stream at every decision: its vehicle's trees do
        # not depend on what other brains planned in the same process (a team flown in one process plans as
        # the team's mission processes do, each alone)
        self._tree_seeds = np.random.default_rng([seed, 0x0D7])

    def _reseed_trees(self) -> None:
        seed_ompl(int(self._tree_seeds.integers(1, 2**31 - 1)))

    # ---------------------------------------------------------------------------- dwell control

    def begin_dwell(self, vehicle: int = 0) -> None:
        self.dwells[vehicle].reset()

    def on_frame(self, hist: topics.Histogram, vehicle: int = 0) -> DwellStatus:
        return self.dwells[vehicle].update(hist.t, hist.total, hist.duration, hist.flags)

    # ---------------------------------------------------------------------------- decisions

    def start(self, current: np.ndarray, vehicle: int = 0,
              reserved: Mapping[int, np.ndarray | Reservation] | None = None) -> TeamDecision:
        self._reseed_trees()
        current = np.asarray(current, dtype=float)
        current = np.r_[current[:2], self.config.altitude_m, current[3]]
        return self._team_explore(vehicle, current, reserved, "start: explore until three readings stand above "
                                                              "background")

    def end_dwell(self, position: np.ndarray, status: DwellStatus, frames: Frames,
                  current: np.ndarray, flown: np.ndarray | None = None, vehicle: int = 0,
                  reserved: Mapping[int, np.ndarray | Reservation] | None = None) -> TeamDecision:
        """Vehicle ``vehicle`` ended a dwell at ``position``; ``frames`` is the team's (:func:`team_frames`),
        ``reserved`` every other live vehicle's reservation (``planner.allocation.reservation``)."""
        self._reseed_trees()
        if self.final is not None:
            return self._again(vehicle)
        self.add_dwell(vehicle, position, status.mean_rate, flown)
        n_dwells = len(self.history)
        if self.phase is Phase.EXPLORE:
            if n_dwells >= self.config.max_dwells:
                return self._team_done(vehicle, "dwell budget spent during exploration", Outcome.BUDGET_SPENT)
            else:
                return self._team_explore(vehicle, current, reserved,
                                          f"explore: {self._above()} of 3 readings above background")
        belief, sigma = self._estimate(frames)
        self._belief, self._sigma = belief, sigma
        misfit = self._misfit()
        stop = self.stop_rule(belief, sigma)  # the one stop rule (mission.search)
        if stop is not None:
            return self._team_done(vehicle, *stop)
        if belief is None:
            return self._team_explore(vehicle, current, reserved, "no estimate yet: keep exploring")
        return self._team_next(vehicle, current, reserved, f"next-best dwell point (1-sigma {sigma:.3f} m{misfit})")

    def add_dwell(self, vehicle: int, position: np.ndarray, mean_rate: float, flown: np.ndarray | None = None
                  ) -> None:
        """A dwell ended (by ``vehicle``: this process's own, or a teammate's as announced on ``team/status``):
        the team's history, explored area, search dwell count and phase (exploration ends once three team
        readings stand above background, paper 003 sec. IV-B-2) take it in."""
        pos = np.asarray(position, dtype=float).reshape(3)
        rate = float(mean_rate) if np.isfinite(mean_rate) else 0.0
        self.history = DwellHistory(np.vstack([self.history.positions, pos]), np.r_[self.history.rates, rate])
        self.dwelled_by.append(int(vehicle))
        if flown is not None and len(flown):
            self.visited = np.vstack([self.visited, np.asarray(flown, dtype=float).reshape(-1, 3)])
        if self.phase is Phase.SEARCH:
            self.search_dwells += 1
            self.search_dwelled_by.append(int(vehicle))
        elif self.phase is Phase.EXPLORE and exploration_done(self.history, self.scenario.background_cps,
                                                              self.config.frontier):
            self.phase = Phase.SEARCH

    def set_pose_variance(self, vehicle: int, var_xy: float, density: float = 0.0) -> None:
        """The vehicle's reported x-y pose variance now (m^2 per axis) and how fast it grows per metre flown
        (``planner.belief.drift_density_from_poses``): its drift margin at the end of a candidate path."""
        self._pose_var[vehicle] = (max(float(var_xy), 0.0), max(float(density), 0.0))

    def var_at_end(self, vehicle: int, path: np.ndarray) -> float:
        """The vehicle's x-y pose variance once it has flown ``path`` (k, >=2)."""
        p = np.asarray(path, dtype=float)[:, :2]
        length = float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0
        var, density = self._pose_var[vehicle]
        return float(var + density * length)

    def replan(self, vehicle: int, current: np.ndarray, reserved: Mapping[int, np.ndarray | Reservation] | None = None
               ) -> TeamDecision:
        """Ask again after a hold (or after a teammate's reservation changed)."""
        self._reseed_trees()
        if self.final is not None:
            return self._again(vehicle)
        if self.phase is Phase.SEARCH and self._belief is not None:
            return self._team_next(vehicle, current, reserved, f"next-best dwell point after a hold "
                                                               f"(1-sigma {self._sigma:.3f} m)")
        return self._team_explore(vehicle, current, reserved, "explore after a hold")

    # ---------------------------------------------------------------------------- allocation

    def _others(self, vehicle: int, reserved: Mapping[int, np.ndarray | Reservation] | None) -> list[Reservation]:
        out = [as_reservation(r) for v, r in (reserved or {}).items() if v != vehicle]
        return [r for r in out if len(r.path)]

    def _clear(self, vehicle: int, path: np.ndarray, others: list[Reservation]) -> bool:
        return path_clear(path, others, self.team.separation_m, self.var_at_end(vehicle, path))

    def _hold(self, vehicle: int, reason: str) -> TeamDecision:
        self.holds += 1
        self._in_row[vehicle] += 1
        if self._in_row[vehicle] > MAX_HOLDS_IN_ROW:
            return TeamDecision(self.phase, None, f"search aborted: no free path for {MAX_HOLDS_IN_ROW} holds in a "
                                                  f"row ({reason})", Outcome.RETIRED, vehicle=vehicle, retire=True)
        return TeamDecision(self.phase, None, f"hold {self.team.hold_s:g} s: {reason}", vehicle=vehicle,
                            hold_s=self.team.hold_s)

    def _team_explore(self, vehicle: int, current: np.ndarray, reserved: Mapping[int, np.ndarray | Reservation] | None,
                      reason: str) -> TeamDecision:
        """Paper 004 frontier exploration, the teammates' reservations pruned from the frontier."""
        cur = self._at_altitude(current)
        others = self._others(vehicle, reserved)
        near = [sample_polyline(r.path if len(r.path) > 1 else np.vstack([r.path, r.path]), 0.25) for r in others]
        pruned = np.vstack([self.visited] + [np.column_stack([xy, np.full(len(xy), cur[2])]) for xy in near])
        for _ in range(3):
            plan = plan_exploration(cur, self.history, self.occ, pruned, self.config.frontier, rng=self.rng)
            if not plan.ok:
                break
            if self._clear(vehicle, plan.path[:, :3], others):
                self._in_row[vehicle] = 0
                return TeamDecision(Phase.EXPLORE, plan, reason, vehicle=vehicle)
            # that frontier's way is taken by a teammate: prune it too and take the next one
            pruned = np.vstack([pruned, plan.dwell_points[:, :3]])
        if not others and not plan.ok:
            return self._team_done(vehicle, "exploration found no frontier left", Outcome.NO_FRONTIER)
        if self._belief is not None and self.phase is Phase.SEARCH:
            return self._team_next(vehicle, current, reserved, reason)
        return self._hold(vehicle, "no frontier with a free path")

    def _team_next(self, vehicle: int, current: np.ndarray, reserved: Mapping[int, np.ndarray | Reservation] | None,
                   reason: str) -> TeamDecision:
        """The next-best dwell point (paper 003 eq. 6) whose path keeps clear of the teammates."""
        assert self._belief is not None
        belief = self._belief
        cur = self._at_altitude(current)
        others = self._others(vehicle, reserved)
        cfg = self.config.next_best
        pending = np.array([r.path[-1] for r in others]).reshape(-1, 3)
        # the teammates' pending dwell points count as taken for eq. 6's repulsion: the team spreads out
        history = DwellHistory(np.vstack([self.history.positions, pending]),
                               np.r_[self.history.rates, np.zeros(len(pending))])
        tree = grow_tree(cur, self.occ, cfg.tree)
        pos = tree.states[:, :3]
        scores = score_nodes(pos, belief, history, self.occ, cfg)
        if not scores.valid.any():
            return self._team_explore(vehicle, current, reserved,
                                      f"no valid next-best dwell point (1-sigma {self._sigma:.3f} m): explore")
        var_now = self._pose_var[vehicle][0]
        free = np.ones(len(pos), dtype=bool)
        for r in others:  # a node too close to a teammate's reservation even before any drift is added
            free &= clearance(pos, [r]) >= required_clearance(self.team.separation_m, var_now, r.var_xy)
        candidates = np.flatnonzero(scores.valid & free)
        for node in candidates[np.argsort(-scores.gain[candidates], kind="stable")][:MAX_CANDIDATES]:
            tree_path = tree.path_to(int(node))
            if not self._clear(vehicle, shortcut_path(tree_path, self.occ), others):
                continue
            path = finish_path(tree_path, cur[3], belief.mean, self.occ, cfg, self.rng)
            if self._clear(vehicle, path[:, :3], others):
                plan = DwellPlan(path[-1:], path, f"team_next_best_{cfg.gain_kind}",
                                 gains=scores.gain[node:node + 1], info={"nodes": len(tree), "node": int(node)})
                self._in_row[vehicle] = 0
                return TeamDecision(Phase.SEARCH, plan, reason, vehicle=vehicle)
        return self._hold(vehicle, "every good dwell point's path crosses a teammate's reservation")

    def _team_done(self, vehicle: int, reason: str, outcome: Outcome) -> TeamDecision:
        self._done(reason, outcome)
        self.final = TeamDecision(Phase.DONE, None, reason, outcome, vehicle=vehicle)
        return self.final

    def _again(self, vehicle: int) -> TeamDecision:
        assert self.final is not None
        return TeamDecision(Phase.DONE, None, self.final.reason, self.final.outcome, vehicle=vehicle)

    def _estimate(self, frames: Frames) -> tuple[SourceBelief | None, float]:
        """The joint estimate from all vehicles' frames; the belief's drift density is the vehicles'
        mean (each vehicle's walk measured on its own frames)."""
        if self.estimator.update(frames, dwell=len(self.history)) is None:
            return None, math.inf
        est = self.estimate
        assert est is not None
        dens = [drift_density_from_poses(f.positions, f.pose_variances, f.dwell) for f in split_walks(frames)]
        return belief_of(est, np.mean(dens, axis=0) if dens else 0.0), est.sigma_m


__all__ = ["MAX_VEHICLES", "TeamBrain", "TeamConfig", "TeamDecision", "home_positions", "split_walks",
           "team_dwell", "team_frames"]
