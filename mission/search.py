"""The search mission's decisions (paper 003 sec. IV-B), with no I/O: what to fly next and when to stop.

Strategy ``active`` (paper 003's autonomous search): ``explore`` (frontier exploration until three
dwell readings stand above background, paper 003 sec. IV-B-2, with paper 004's frontier choice), then
``search`` (estimate the source from every frame recorded so far with ``estimator.inflight``, the
estimate ``radseek replay`` reproduces, then fly to the next-best dwell point of the random tree scored
with eq. 6), until the source's 1-sigma (x-y) position ellipse is smaller than ``stop_sigma_m``, the
estimate is stable and its model fits the counts (goodness of fit p >= ``estimator.inflight.GOOD_FIT_P``),
or the same holds of an ellipse that has stopped shrinking at the floor odometry drift allows (drift-limited:
a larger scene flies more metres, and its drift bound may lie above ``stop_sigma_m``), or the dwell budget is
spent. Strategy ``info`` is the same search with the information planner (``planner.information``) in place of
eq. 6 (and exploration ended after ``info_min_readings`` readings): the next dwell point and its length by the
expected D-optimal information per second under drift; it is
drift-limited when no next leg is expected to lower the bound the flown frames allow (landmark-aware: mapped walls
pin the drift) by more than ``bound_fall_m_s`` per second of flight.
An active search about to stop found on a one-source estimate whose background stands above the operator's
(``estimator.inflight.background_excess_z`` > ``CHECK_EXCESS_Z``: a far source's flux read as background) first
flies up to ``excess_checks`` check dwells ``check_distance_m`` from the estimate, towards where a source the flight
has not seen would give the most flux (``unseen_flux``), so that such a source shows itself to the second-source
test; check dwells spend no search budget.
Strategies ``lattice`` (paper 003's 9-point lattice) and
``lawnmower`` fly a fixed pattern over the bounds instead: the baselines of the benchmarks.

The brain sees only what the vehicle and detector report (estimated poses, histograms) and the
operator's scenario; it never sees the truth. Two drivers run it: ``mission.mission_process`` over
MAVLink and zenoh, and ``launch.offline`` in-process for seeded benchmarks.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
from scipy.spatial import cKDTree

from estimator.inflight import (
    DEFAULT_LOCALIZER,
    DEFAULT_SETTINGS,
    GOOD_FIT_P,
    WARM_SIGMA_M,
    InflightEstimator,
)
from planner.baselines import fixed_lattice, lawnmower
from planner.belief import DwellHistory, SourceBelief, drift_density_from_poses
from planner.dwell_controller import DwellConfig, DwellController, DwellStatus
from planner.dwell_tree import grow_tree, shortcut_path
from planner.exploration import FrontierConfig, exploration_done, plan_exploration
from planner.next_best import NextBestConfig, plan_next_dwell
from planner.occupancy import OccupancyMap
from planner.plan import DwellPlan
from radseek import topics
from radseek.dataset import Frames, Scenario
from radseek.estimate import SourceEstimate
from radseek.geometry import path_lengths, semi_major_axis
from radseek.outcome import Outcome, parse_outcome


class Phase(StrEnum):
    EXPLORE = "explore"
    SEARCH = "search"
    PATTERN = "pattern"
    DONE = "done"


STRATEGIES = ("active", "info", "lattice", "lawnmower")
#: the strategies that search actively (explore, then next-best dwell points): ``active`` scores the tree with
#: paper 003's eq. 6 (``next_best.gain_kind``), ``info`` with the information planner (``planner.information``:
#: D-optimal under drift, dwell length by information per second)
ACTIVE = ("active", "info")
#: the drift-limited stop: the 1-sigma is less than 5 % below the best of the two dwells before ...
PLATEAU = 0.95
#: ... and is within 25 % of the floor the odometry drift alone allows
AT_FLOOR = 1.25
#: m: a search dwell planned from a belief whose 1-sigma is above this (the source not yet localised: the
#: in-flight fit's own confidence limit, ``estimator.inflight.WARM_SIGMA_M``) does not spend the search budget
LOCALISED_M = WARM_SIGMA_M
#: a two-source estimate is found only once its source's fitted strength stands this many sd above the other's
#: (``estimator.inflight.strength_order_z``): until then the counts have not decided which source is the stronger,
#: so which one the record reports, and the planner plans for the source whose strength is the less known
#: (two-source seed 160: 1364 +- 73 against 1040 +- 592 cps, 0.5 sd, and the search stopped reporting the weaker
#: source)
STRENGTH_ORDER_Z = 2.0
#: a search about to stop on a one-source estimate whose background stands more than this many sd above the
#: operator's (``estimator.inflight.background_excess_z``) flies check dwells first: the one-sided 2.3 % tail. At
#: ``BACKGROUND_EXCESS_Z`` (3.09, the second-source test's own trigger) 11 of the 15 two-source info flights that
#: ended on one source and missed had never checked (z 1.0-3.1)
CHECK_EXCESS_Z = 2.0
#: bearings (most unseen flux first) a check dwell tries to route to before it gives up: each may grow a tree
CHECK_ROUTES = 8


@dataclass(frozen=True)
class SearchConfig:
    """Mission settings (units in comments)."""

    strategy: str = "active"  # one of STRATEGIES
    altitude_m: float = 1.5  # m above the floor for every dwell point
    pattern_spacing_m: float | None = None  # lattice / lawnmower spacing (None: a quarter of the bounds)
    stop_sigma_m: float = 0.10  # m: stop when the source's 1-sigma semi-major axis (x-y) is below this
    min_search_dwells: int = 2  # dwell points after exploration before the sigma criterion may stop
    #: stop "drift-limited" when the 1-sigma has stopped falling at the odometry-drift floor (False: fly on to the
    #: sigma target or the budget, as ``benchmarks/error_along_flight.py`` does to see what more dwells buy)
    stop_at_drift_floor: bool = True
    #: m/s: strategy ``info`` stops drift-limited when no valid next leg is expected to lower the bound the
    #: flown frames allow (the planner's drift-aware bound, landmark-aware on walled scenes: the one the fit
    #: reaches) by more than this per second of flight (0: never by this rule): 10 s of flight would buy < 2 mm.
    #: Tuned on seeds 1000-1039 only (``benchmarks/stop_rule_tuning.py``, docs/planner.md)
    bound_fall_m_s: float = 2e-4
    max_search_dwells: int = 6  # dwell points after exploration (paper 003 needed 5)
    max_dwells: int = 16  # dwell points in all (battery budget)
    #: the in-flight estimate (``estimator.inflight``: pooling, warm start, wall test, sigma) fits this
    #: localizer with these settings after every dwell
    localizer: str = DEFAULT_LOCALIZER
    localizer_settings: dict = field(default_factory=lambda: dict(DEFAULT_SETTINGS))
    vehicle_radius_m: float = 0.3
    dwell: DwellConfig = field(default_factory=DwellConfig)
    frontier: FrontierConfig = field(default_factory=FrontierConfig)
    #: readings above background that end the ``info`` search's exploration (the others: the frontier's
    #: ``min_readings``, paper 003's three): its score plans from the first in-flight fit, and each exploration
    #: dwell flown first adds drift to the informative counts that follow (docs/planner.md, issue 36)
    info_min_readings: int = 2
    #: check dwells before an active search stops found on an estimate with an excess background (0: none), and
    #: how far from the estimate (m): ``SearchBrain._check_excess``. Without them the information planner's
    #: two-source flights kept the one-source model in 107 of 200 (its dwells hug the strong source), covering the
    #: truth in 67 % of those
    excess_checks: int = 2
    check_distance_m: float = 3.0
    next_best: NextBestConfig = field(default_factory=NextBestConfig)

    def __post_init__(self) -> None:
        if self.altitude_m <= 0 or self.stop_sigma_m <= 0:
            raise ValueError("altitude_m and stop_sigma_m must be > 0")
        if self.info_min_readings < 1:
            raise ValueError("info_min_readings must be >= 1")
        if self.excess_checks < 0 or not self.check_distance_m > 0:
            raise ValueError("need excess_checks >= 0 and check_distance_m > 0")
        if not self.bound_fall_m_s >= 0:
            raise ValueError("bound_fall_m_s must be >= 0")
        if not (0 <= self.min_search_dwells <= self.max_search_dwells <= self.max_dwells):
            raise ValueError("need 0 <= min_search_dwells <= max_search_dwells <= max_dwells")
        if self.strategy not in STRATEGIES:
            raise ValueError(f"strategy must be one of {STRATEGIES}, got {self.strategy!r}")

    @property
    def exploration(self) -> FrontierConfig:
        """The exploration settings: ``frontier``, ended after ``info_min_readings`` readings when the strategy is
        ``info``."""
        if self.strategy == "info":
            return dataclasses.replace(self.frontier, min_readings=self.info_min_readings)
        return self.frontier

    @property
    def planner(self) -> NextBestConfig:
        """The next-best settings the search plans with: ``next_best``, scored by the information planner
        when the strategy is ``info``."""
        if self.strategy == "info":
            return dataclasses.replace(self.next_best, gain_kind="info")
        return self.next_best


@dataclass(frozen=True)
class Decision:
    """What to do next: fly ``plan`` (path, then dwell at its dwell point) or stop (``plan`` None). ``reason``
    is for people; a stop's ``outcome`` (:class:`radseek.outcome.Outcome`) is for programs (None while the
    search goes on)."""

    phase: Phase
    plan: DwellPlan | None
    reason: str
    outcome: Outcome | None = None


class SearchBrain:
    """Feed it dwell results; it answers with the next plan. Pure apart from the seeded planner RNG."""

    def __init__(self, scenario: Scenario, config: SearchConfig | None = None, seed: int = 0):
        self.scenario = scenario
        self.config = config or SearchConfig()
        z = self.config.altitude_m
        self.occ = OccupancyMap.from_scenario(scenario, self.config.vehicle_radius_m, flight_z=(z - 0.5, z + 0.5))
        self.rng = np.random.default_rng(seed)
        self.history = DwellHistory()
        self.dwell = DwellController(self.config.dwell)
        self.phase = Phase.EXPLORE
        self.search_dwells = 0
        self.check_dwells = 0  # search dwells flown to check an excess background (_check_excess)
        self.estimator = InflightEstimator(scenario, self.config.localizer, self.config.localizer_settings)
        self.visited = np.zeros((0, 3))
        self.pattern: list[np.ndarray] = []
        self.next_dwell_s: float | None = None  # s: the length the planner chose for the next dwell (None: the rule)
        #: strategy ``info``, one per search decision: (dwells so far, the planner's bound of the flown frames (m),
        #: its largest expected fall per second of the next leg (m/s)), what the drift-limited stop looked at
        self.bound_falls: list[tuple[int, float, float]] = []

    # ---------------------------------------------------------------------------- dwell control

    def begin_dwell(self) -> None:
        """A new dwell: the automated dwell time (paper 003 sec. III-E), or exactly the length the information
        planner chose for this dwell point."""
        cfg = self.config.dwell
        if self.next_dwell_s is not None:
            t = float(np.clip(self.next_dwell_s, 0.0, cfg.t_timeout))
            cfg = dataclasses.replace(cfg, t_min=t, t_max=t)
        self.dwell = DwellController(cfg)

    def on_frame(self, hist: topics.Histogram) -> DwellStatus:
        """One histogram during a dwell: the dwell controller's verdict (``done`` ends the dwell)."""
        return self.dwell.update(hist.t, hist.total, hist.duration, hist.flags)

    # ---------------------------------------------------------------------------- decisions

    def start(self, current: np.ndarray) -> Decision:
        """The first plan from the take-off pose (x, y, z, yaw)."""
        current = np.asarray(current, dtype=float)
        current = np.r_[current[:2], self.config.altitude_m, current[3]]
        if self.config.strategy not in ACTIVE:
            self.phase = Phase.PATTERN
            self.pattern = list(self._pattern_points())
            return self._next_pattern_point(current)
        return self._explore(current, f"start: explore until {self.config.exploration.min_readings} readings stand "
                                      "above background")

    def end_dwell(self, position: np.ndarray, status: DwellStatus, frames: Frames, current: np.ndarray,
                  flown: np.ndarray | None = None) -> Decision:
        """A dwell ended at ``position`` (estimated, (3,)) with ``status``; ``frames`` is everything
        recorded so far (usable frames), ``current`` the pose (x, y, z, yaw) now, ``flown`` positions
        visited since the last call (for exploration)."""
        pos = np.asarray(position, dtype=float).reshape(3)
        self.next_dwell_s = None
        rate = status.mean_rate if np.isfinite(status.mean_rate) else 0.0
        self.history = DwellHistory(np.vstack([self.history.positions, pos]), np.r_[self.history.rates, rate])
        if flown is not None and len(flown):
            self.visited = np.vstack([self.visited, np.asarray(flown, dtype=float).reshape(-1, 3)])
        if self.phase is Phase.SEARCH:
            self.search_dwells += 1
        n_dwells = len(self.history)
        if self.phase is Phase.PATTERN:
            _, sigma = self._estimate(frames)
            if not self.pattern or n_dwells >= self.config.max_dwells:
                return self._done(f"{self.config.strategy} pattern flown (1-sigma {sigma:.3f} m)",
                                  Outcome.PATTERN_FLOWN)
            return self._next_pattern_point(current)
        if self.phase is Phase.EXPLORE:
            if exploration_done(self.history, self.scenario.background_cps, self.config.exploration):
                self.phase = Phase.SEARCH
            elif n_dwells >= self.config.max_dwells:
                return self._done("dwell budget spent during exploration", Outcome.BUDGET_SPENT)
            else:
                need = self.config.exploration.min_readings
                return self._explore(current, f"explore: {self._above()} of {need} readings above background")
        belief, sigma = self._estimate(frames)
        misfit = self._misfit()
        # the information planner plans before the stop rule: its score says what the next leg would still buy
        plan = self._plan_next(current, frames, belief) if belief is not None and self.config.strategy == "info" \
            else None
        fall = None
        if plan is not None and "bound_fall_m_s" in plan.info:
            fall = plan.info["bound_fall_m_s"]
            self.bound_falls.append((n_dwells, plan.info["bound_m"], fall))
        stop = self.stop_rule(belief, sigma, fall)
        if stop is not None and stop[1] in (Outcome.FOUND, Outcome.DRIFT_LIMITED):
            check = self._check_excess(current, frames)
            if check is not None:
                return check
        if stop is not None:
            return self._done(*stop)
        if belief is None:
            return self._explore(current, "no estimate yet: keep exploring")
        plan = plan if plan is not None else self._plan_next(current, frames, belief)
        if not plan.ok:
            # every tree node inside the belief's ellipse or predicted too weak (a broad early belief covers
            # the whole tree): gather counts where none were taken yet rather than give up with budget left
            return self._explore(current, f"no valid next-best dwell point (1-sigma {sigma:.3f} m): explore")
        self.next_dwell_s = plan.info.get("dwell_s")
        dwell = f", dwell {self.next_dwell_s:g} s" if self.next_dwell_s is not None else ""
        return Decision(Phase.SEARCH, plan, f"next-best dwell point (1-sigma {sigma:.3f} m{misfit}{dwell})")

    def stop_rule(self, belief: SourceBelief | None, sigma: float,
                  bound_fall_m_s: float | None = None) -> tuple[str, Outcome] | None:
        """Whether the search stops after the estimate ``belief`` (1-sigma ``sigma`` m) of the dwells so far, and
        why (the reason for people, the outcome for programs), else None (paper 003 sec. IV-B-4: found when the
        1-sigma is below ``stop_sigma_m``; here also when it is drift-limited, and never on a misfitting or
        unstable estimate; the budget spent otherwise). Drift-limited: with ``bound_fall_m_s`` (the information
        planner's largest expected fall of the flown frames' bound per second of a next leg, m/s) when that is
        below ``bound_fall_m_s`` of the config, else (eq. 6, a team) when the 1-sigma has stopped falling at the
        landmark-free drift floor. One rule for one vehicle and a team."""
        misfit, undecided = self._misfit(), self._undecided()
        searched = belief is not None and self.search_dwells >= self.config.min_search_dwells and not undecided
        if searched and sigma < self.config.stop_sigma_m and self._stable() and not misfit:
            return f"source found: 1-sigma {sigma:.3f} m < {self.config.stop_sigma_m} m", Outcome.FOUND
        spent = self._budget_dwells() >= self.config.max_search_dwells or len(self.history) >= self.config.max_dwells
        if bound_fall_m_s is not None:
            limit = self.config.bound_fall_m_s
            # with the budget spent no next leg is flown: the bound has fallen as far as this flight allows
            fall = 0.0 if spent else bound_fall_m_s
            if (self.config.stop_at_drift_floor and limit > 0 and searched and sigma < LOCALISED_M and fall < limit
                    and self._stable() and not misfit):
                bound = self.bound_falls[-1][1] if self.bound_falls else math.nan
                return (f"source found: 1-sigma {sigma:.3f} m, drift-limited (the bound these frames allow, "
                        f"{bound:.3f} m: " + ("the dwell budget allows no next leg)" if spent else
                           f"it would fall by {1e3 * fall:.2f} mm per second of a next leg, < {1e3 * limit:g})"),
                        Outcome.DRIFT_LIMITED)
            floor = 0.0
        else:
            floor = self._drift_limited() if self.config.stop_at_drift_floor else 0.0
        if searched and floor and self._stable() and not misfit:
            return (f"source found: 1-sigma {sigma:.3f} m, drift-limited (stopped falling at the odometry-drift "
                    f"floor {floor:.3f} m; the {self.config.stop_sigma_m} m target is below what this flight's "
                    "drift allows)", Outcome.DRIFT_LIMITED)
        if spent:
            return f"dwell budget spent (1-sigma {sigma:.3f} m{misfit}{undecided})", \
                Outcome.MISFIT if misfit else Outcome.BUDGET_SPENT
        return None

    # ---------------------------------------------------------------------------- helpers

    def _above(self) -> int:
        return int(self.history.above_background(self.scenario.background_cps, self.config.frontier.k_sigma,
                                                 self.config.frontier.dwell_s).sum())

    def _at_altitude(self, current: np.ndarray) -> np.ndarray:
        c = np.asarray(current, dtype=float).copy()
        c[2] = float(np.clip(self.config.altitude_m, self.occ.bounds_min[2], self.occ.bounds_max[2]))
        c[:2] = np.clip(c[:2], self.occ.free_min[:2], self.occ.free_max[:2])
        free = self.occ.nearest_valid(c[:3])  # arrived within the acceptance radius of a clearance edge
        if free is not None:
            c[:3] = free
        return c

    def _explore(self, current: np.ndarray, reason: str) -> Decision:
        plan = plan_exploration(self._at_altitude(current), self.history, self.occ, self.visited,
                                self.config.exploration, rng=self.rng)
        if not plan.ok:
            return self._done("exploration found no frontier left", Outcome.NO_FRONTIER)
        return Decision(Phase.EXPLORE, plan, reason)

    def _plan_next(self, current: np.ndarray, frames: Frames, belief: SourceBelief) -> DwellPlan:
        """The next-best dwell point from ``current`` for ``belief`` after ``frames``."""
        var_now = (np.array([frames.var_x[-1], frames.var_y[-1], frames.var_z[-1]], dtype=float) if len(frames.t)
                   else np.zeros(3))
        return plan_next_dwell(self._at_altitude(current), belief, self.history, self.occ,
                               self._planner(frames, belief), rng=self.rng, frames=frames,
                               pose_var_now=np.where(np.isfinite(var_now), var_now, 0.0))

    def _planner(self, frames: Frames | None = None, belief: SourceBelief | None = None) -> NextBestConfig:
        """The planner's settings for the next dwell: the information planner predicts the rate through the
        walls with the attenuation the in-flight fit estimated (the localizers' model, ``wall_attenuation``);
        while no flown line of sight to the belief's source has crossed a mapped wall the fit has no
        attenuation to estimate, and the score assumes ``InfoConfig.wall_mu_prior_per_m`` (the walls' shadow
        edges tell the drift, and with mu = 0 the score cannot see them). A wall crossed and still no walled
        fit: the walls were tested and do not attenuate (mu 0)."""
        cfg = self.config.planner
        if cfg.gain_kind != "info" or not self.occ.walls:
            return cfg
        mu = self.estimate.params.get("wall_attenuation.mu_per_m") if self.estimate is not None else None
        if mu is None and frames is not None and belief is not None and not self._walls_crossed(frames, belief):
            mu = cfg.info.wall_mu_prior_per_m
        if mu is not None and math.isfinite(mu) and mu > 0:
            cfg = dataclasses.replace(cfg, wall_mu_per_m=float(mu))
        return cfg

    def _walls_crossed(self, frames: Frames, belief: SourceBelief) -> bool:
        """Whether a line of sight from a flown dwell to the belief's source crosses a mapped wall."""
        dwell = np.asarray(frames.dwell) >= 0
        if not dwell.any():
            return False
        pos = np.column_stack([frames.x, frames.y, frames.z])[dwell]
        return bool((path_lengths(pos, belief.mean, self.occ.walls) > 0).any())

    def _misfit(self) -> str:
        """A note when the last estimate's goodness of fit fails (p < ``GOOD_FIT_P``: the model misses
        something, so its small ellipse is no found source), else ''."""
        p = self.estimate.p_value if self.estimate else math.nan
        return f"; the model misses something, fit p = {p:.2g}" if p < GOOD_FIT_P else ""

    def _undecided(self) -> str:
        """A note when the last estimate has two sources and the counts have not decided which is the stronger
        (``strength_order_z`` below :data:`STRENGTH_ORDER_Z`, or unknown), else ''."""
        est = self.estimate
        if est is None or "second_source" not in est.effects:
            return ""
        z = float(est.extra.get("strength_order_z", math.nan))
        return "" if z >= STRENGTH_ORDER_Z else f"; which source is the stronger is undecided ({z:.1f} sd)"

    def _budget_dwells(self) -> int:
        """Search dwells that spend ``max_search_dwells``: those planned from a localised belief (1-sigma below
        ``LOCALISED_M``). Each in-flight estimate but the last planned one search dwell; one with a 1-sigma of
        metres (outdoor: exploration ends with three readings above background 10-20 m from a 60000 cps
        source, and the first 1-4 search estimates have a 1-sigma of 1-70 m) aimed at nothing yet, and
        counting it ended 2 of 80 outdoor searches "budget spent" one or two dwells short of the drift floor.
        ``max_dwells`` still bounds the whole search."""
        wide = sum(not e.sigma_m < LOCALISED_M for e in self.estimates[:-1])
        return max(self.search_dwells - wide - self.check_dwells, 0)

    def _drift_limited(self) -> float:
        """The drift floor (m) when the estimate is drift-limited, else 0: its 1-sigma is less than ``1 -
        PLATEAU`` below the best of the (up to two) estimates of the dwells just before it, and within
        ``AT_FLOOR`` of the floor odometry drift alone allows (``drift_floor_m``: the drift-aware bound's
        semi-major axis), a floor itself within ``AT_FLOOR`` of the drift so far (``pose_sd_m``). More
        dwells then buy nothing: each adds metres, so drift, about as fast as counts.
        The best of two, not the last alone: at the floor the 1-sigma scatters by a few centimetres from dwell
        to dwell (real stack, outdoor: 0.152, 0.182, 0.159 m at a 0.14-0.15 m floor, and the search spent its
        budget because each dwell compared only with a worse or a better neighbour)."""
        last = self.estimates[-3:]
        now = last[-1] if last else None
        before = [e for e in last[:-1] if now.dwell - e.dwell <= 2] if now else []
        if not before or before[-1].dwell != now.dwell - 1:
            return 0.0
        s_before = min(e.sigma_m for e in before)
        floor = now.drift_floor_m
        if not (np.isfinite([s_before, now.sigma_m]).all() and math.isfinite(floor) and floor > 0):
            return 0.0
        # a floor far above the drift itself is the geometry's (few counts, one side), not the drift's: no
        # stop there (outdoor: "found, drift-limited" at 1-sigma 1-20 m in 8 of 200 searches without this)
        if not floor <= AT_FLOOR * now.pose_sd_m:
            return 0.0
        return floor if now.sigma_m >= PLATEAU * s_before and now.sigma_m <= AT_FLOOR * floor else 0.0

    def _stable(self) -> bool:
        """The last two estimates agree within 2 combined x-y ellipse sizes: a small ellipse around an
        estimate that is still jumping between likelihood modes (few dwells, all on one side) is not a found
        source. The sizes are the ellipses' geometric semi-major axes, trusted or not (the stop rule already
        asks the last estimate's ``sigma_m`` to be trustworthy)."""
        if len(self.estimates) < 2:
            return False
        a, b = self.estimates[-2], self.estimates[-1]
        sa, sb = (semi_major_axis(e.covariance[:2, :2]) for e in (a, b))
        return math.hypot(a.x - b.x, a.y - b.y) < 2 * math.hypot(sa, sb)

    def _pattern_points(self) -> np.ndarray:
        lo, hi = self.occ.free_min, self.occ.free_max
        z = float(np.clip(self.config.altitude_m, lo[2], hi[2]))
        spacing = self.config.pattern_spacing_m or float(np.clip(min(hi[:2] - lo[:2]) / 4, 0.5, 5.0))
        if self.config.strategy == "lattice":
            pts = fixed_lattice(np.r_[(lo[:2] + hi[:2]) / 2, z], spacing)
        else:
            pts = lawnmower(lo, hi, spacing, z, margin=0.0)
        return pts[self.occ.points_valid(pts)]

    def _next_pattern_point(self, current: np.ndarray) -> Decision:
        start = self._at_altitude(current)
        while self.pattern:
            plan = self._plan_to(start, self.pattern.pop(0), self.config.strategy)
            if plan is not None:
                return Decision(Phase.PATTERN, plan, f"{self.config.strategy}: {len(self.pattern)} points left")
        return self._done(f"{self.config.strategy} pattern flown", Outcome.PATTERN_FLOWN)

    def _check_excess(self, current: np.ndarray, frames: Frames) -> Decision | None:
        """A check dwell before stopping found, or None: the in-flight estimate has one source and its background
        stands more than :data:`CHECK_EXCESS_Z` sd above the operator's, and fewer than ``excess_checks`` checks
        were flown. Where the excess comes from is not known (a background gradient fitted to a few dwells hugging
        the source pointed away from the second one on two-source seed 0), so the dwell point is the one
        ``check_distance_m`` from the estimate (of 32 bearings, in the free volume, reachable) that would see the
        most flux from a source the flight so far has not seen (:func:`unseen_flux` over every recorded pose):
        a source there out-counts the background several times over, and the next estimate's second-source test
        sees it. The counts there pin the background too. (The bearing farthest from every dwell, before: on
        two-source seed 88 both checks went west and north of dwells hugging the source from the south-west,
        and the second source is east.)"""
        est = self.estimator.estimate
        if (est is None or self.check_dwells >= self.config.excess_checks or "second_source" in est["effects"]
                or len(self.history) >= self.config.max_dwells  # the battery budget holds for checks too
                or not est.get("background_excess_z", math.nan) > CHECK_EXCESS_Z):
            return None
        start = self._at_altitude(current)
        bearings = np.linspace(0.0, 2.0 * math.pi, 32, endpoint=False)
        points = np.c_[est["x"] + self.config.check_distance_m * np.cos(bearings),
                       est["y"] + self.config.check_distance_m * np.sin(bearings), np.full(32, start[2])]
        points[:, :2] = np.clip(points[:, :2], self.occ.free_min[:2], self.occ.free_max[:2])
        flown = np.vstack([self.history.positions, np.column_stack([frames.x, frames.y, frames.z])])
        score = unseen_flux(points, flown, self.occ.free_min[:2], self.occ.free_max[:2], est["z"])
        for k in np.argsort(-score)[:CHECK_ROUTES]:
            target = self.occ.nearest_valid(points[k])
            plan = None if target is None else self._plan_to(start, target, "excess-check")
            if plan is not None:
                break
        else:
            return None
        self.check_dwells += 1
        return Decision(Phase.SEARCH, plan, (
            f"check: background {est['background_cps']:.0f} cps stands {est['background_excess_z']:.1f} sd above "
            f"the operator's {self.scenario.background_cps:g}; dwell {self.config.check_distance_m:g} m from the "
            "estimate, where no dwell was, before stopping"))

    def _plan_to(self, start: np.ndarray, target: np.ndarray, method: str) -> DwellPlan | None:
        """One dwell point at ``target`` (x, y, z) reached along :meth:`_route`, holding ``start``'s yaw; None if
        no route."""
        path = self._route(start, target)
        if path is None:
            return None
        yaw = np.full((len(path), 1), start[3])
        return DwellPlan(np.r_[target, start[3]][None, :], np.hstack([path, yaw]), method)

    def _route(self, start: np.ndarray, target: np.ndarray) -> np.ndarray | None:
        """Collision-free polyline (k, 3) from start to target: straight if possible, else along a tree."""
        if self.occ.segment_valid(start[:3], target):
            return np.vstack([start[:3], target])
        tree = grow_tree(start, self.occ, self.config.next_best.tree)
        pos = tree.states[:, :3]
        order = np.argsort(np.linalg.norm(pos - target, axis=1))
        for node in order[:50]:
            if self.occ.segment_valid(pos[node], target):
                return np.vstack([shortcut_path(tree.path_to(int(node)), self.occ), target])
        return None

    def _done(self, reason: str, outcome: Outcome) -> Decision:
        self.phase = Phase.DONE
        self.estimator.finalize()  # the final estimate gets its drift-aware bound and 95 % ellipse, once
        return Decision(Phase.DONE, None, reason, outcome)

    def _estimate(self, frames: Frames) -> tuple[SourceBelief | None, float]:
        """The in-flight estimate from every frame recorded so far (``estimator.inflight``) as the
        planner's belief, with its 1-sigma (inf when there is none or it is not trustworthy). With two sources
        whose strength order is undecided (:meth:`_undecided`) the belief is the source whose strength is the
        less known, which may be the one the record does not report."""
        if self.estimator.update(frames, dwell=len(self.history)) is None:
            return None, math.inf
        est = self.estimate
        assert est is not None
        dens = drift_density_from_poses(frames.positions, frames.pose_variances, frames.dwell)
        other = self.estimator.other_source() if self._undecided() else None
        if other is not None and other["cps_sd"] > other["reported_cps_sd"]:
            # plan for the source whose strength is the less known: its counts decide which one is the stronger
            est = dataclasses.replace(est, **{k: other[k] for k in ("x", "y", "z", "cps_at_1m", "covariance")})
        return belief_of(est, dens), self.estimate.sigma_m

    @property
    def estimates(self) -> list[SourceEstimate]:
        """The in-flight estimate records (``estimator.inflight``, typed), one per dwell from the first search
        estimate on."""
        return [SourceEstimate.from_json(e) for e in self.estimator.estimates]

    @property
    def estimate(self) -> SourceEstimate | None:
        """The last in-flight estimate (with ``bound_m`` and ``ellipse_95`` once the search is done)."""
        last = self.estimator.estimate
        return None if last is None else SourceEstimate.from_json(last)


def unseen_flux(points: np.ndarray, flown: np.ndarray, lo: np.ndarray, hi: np.ndarray, z: float,
                cells_per_side: int = 40) -> np.ndarray:
    """(k,) how much flux each of ``points`` (k, 3) would see from a source the flight has not seen: a source at
    a cell c of a grid over [``lo``, ``hi``] (x, y) at height ``z`` unseen from the ``flown`` positions (n, 3) can
    be as strong as ~ d(c)^2, its squared distance to the nearest flown position (inverse square law), so at p it
    gives ~ d(c)^2 / |p - c|^2; summed over the cells (where it is: uniform over the grid)."""
    gx, gy = (np.linspace(lo[i], hi[i], cells_per_side) for i in range(2))
    cells = np.c_[np.repeat(gx, len(gy)), np.tile(gy, len(gx)), np.full(len(gx) * len(gy), z)]
    flown = np.asarray(flown, dtype=float)
    d2 = cKDTree(flown[np.isfinite(flown).all(axis=1)]).query(cells)[0] ** 2  # a frame without a pose: not flown
    r2 = ((np.asarray(points, dtype=float)[:, None, :] - cells[None, :, :]) ** 2).sum(axis=2)
    floor = (max(hi[0] - lo[0], hi[1] - lo[1]) / cells_per_side) ** 2  # a cell's own size: no 1/0 on a cell
    return (d2[None, :] / np.maximum(r2, floor)).sum(axis=1)


def belief_of(est: SourceEstimate, drift_density: np.ndarray | float = 0.0) -> SourceBelief:
    """The planner's belief (paper 003 sec. IV-B-3) of an in-flight estimate: strength and background
    clipped to the belief's domain (> 0, >= 0)."""
    return SourceBelief(est.position, est.covariance, max(est.cps_at_1m, 1e-3), max(est.background_cps, 0.0),
                        drift_density)


def search_failure(mission_summary: dict) -> str | None:
    """Why the search failed, from the mission's summary (its ``outcome``); None when it located the source.
    A summary without a known ``outcome`` counts as not located."""
    reason = str(mission_summary.get("reason", ""))
    outcome = parse_outcome(mission_summary.get("outcome"))
    if outcome is not None and outcome.aborted:
        return reason
    if mission_summary.get("estimate") is None:
        return f"no source estimate ({reason})"
    if outcome is not None and outcome.located:
        return None
    return f"no source found: {reason}"


def reproducible(config: SearchConfig) -> SearchConfig:
    """The search settings with every planning tree bounded by its node count (N_max) instead of a wall
    time budget: a tree grown "for 0.2 s" depends on the machine's load, so the same seed would plan
    differently. With lockstep the wall time costs no flight time; a 30 s hard limit stays as a guard."""
    def tree(t):
        return dataclasses.replace(t, time_budget=math.inf, time_limit=max(t.time_limit, 30.0))

    return dataclasses.replace(
        config, frontier=dataclasses.replace(config.frontier, tree=tree(config.frontier.tree)),
        next_best=dataclasses.replace(config.next_best, tree=tree(config.next_best.tree)))
