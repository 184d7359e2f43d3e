"""The team's mission: the one executive (``mission.executive``) with the team brain (``mission.team``)
deciding jointly and a ``TeamLink`` carrying what the teammates say.

Each vehicle flies its own executive; they share nothing but the link: statuses (where each is, the path it
reserved, its dwells), each other's frames, and the joint estimate. A plan is claimed before it is flown: of
two crossing claims the later one yields (``TeamLink.earlier_crossing``). The link is zenoh between mission
processes (``mission.mission_process._Team``) or shared memory between executives in one process
(``launch.offline_team``).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from mission.executive import MissionExecutive
from mission.search import Decision, Phase, SearchBrain, SearchConfig
from mission.team import TeamBrain, TeamDecision
from planner.allocation import Reservation
from planner.belief import drift_density_from_poses
from radseek import topics
from radseek.dataset import Frames, Scenario
from radseek.outcome import Outcome

CLAIM_ATTEMPTS = 5  # claims yielded in a row before the vehicle holds instead
#: sim s a vehicle hovers for its teammates to say where they are before it plans without them
START_WAIT_SIM_S = 60.0


class TeamLink(Protocol):
    """This vehicle's side of the team's traffic."""

    index: int  # this vehicle's team index
    state: str  # this vehicle's state as it last said it (``topics.TEAM_STATES``)
    names: tuple[str, ...]  # the team's vehicle names, by index
    mates: dict  # teammate name -> its stream (anything)

    def set(self, t: float, state: str, reservation: np.ndarray, var_xy: float | None = None) -> None: ...

    def claim(self, t: float, path: np.ndarray, var_xy: float) -> float:
        """Announce ``path`` as this vehicle's reservation; returns the claim's stamp."""

    def done_with(self, t: float) -> None:
        """This vehicle has fully handled its frame ending at ``t``."""

    async def wait_turn(self, t_next: float, frame_s: float) -> None:
        """Until this vehicle's turn to take its frame ending at ``t_next`` (``mission.team_link``)."""

    def earlier_crossing(self, path: np.ndarray, stamp: float, separation: float, var_xy: float) -> str | None: ...

    def add_dwell(self, index: int, position: np.ndarray, mean_rate: float, t_first: float, t_last: float,
                  flown: np.ndarray) -> None: ...

    def finish(self, t: float, reason: str, decided: bool, outcome: Outcome | None = None) -> None: ...

    def publish_estimate(self, msg: topics.Estimate) -> None: ...

    def reserved(self) -> dict[int, Reservation]: ...

    def over(self) -> Decision | None: ...

    def newly_silent(self) -> list[tuple[str, str]]: ...

    def new_dwells(self) -> list[tuple[int, dict, np.ndarray | None]]: ...

    def frames(self, own: Frames) -> Frames: ...


class TeamExecutive(MissionExecutive):
    """One vehicle of a team: the executive whose search is the team brain's, over ``team``."""

    brain: TeamBrain

    def __init__(self, scenario: Scenario, config: SearchConfig, brain: SearchBrain, team: TeamLink, **kw):
        super().__init__(scenario, config, brain, **kw)
        self.team = team

    def search_over(self) -> Decision | None:
        """The team's search's end when a teammate's estimate ended it, else None."""
        return self.team.over()

    def on_tick(self) -> None:
        self.team.done_with(self.t)
        for name, why in self.team.newly_silent():
            self.event("teammate_lost", vehicle=name, why=why)

    async def tick(self, **kw) -> topics.Histogram | None:
        """The next frame, taken in the team's turn (``mission.team_link``)."""
        self.on_tick()
        if self.team.state != "done":  # its search over, it lands on its own
            await self.team.wait_turn(self.t + self.frames.frame_s, self.frames.frame_s)
        return await self.frames.tick(**kw)

    def publish_estimate(self) -> None:
        msg = self.brain.estimator.message(self.t)
        if msg is not None:
            self.publish(msg)
            self.team.publish_estimate(msg)  # the joint estimate, on the team's one key

    def _ingest_team(self) -> None:
        """Hand the teammates' newly announced dwells to the team brain."""
        assert self.team is not None and isinstance(self.brain, TeamBrain)
        for index, dwell, flown in self.team.new_dwells():
            self.brain.add_dwell(index, np.array([dwell["x"], dwell["y"], dwell["z"]]), dwell["mean_rate"], flown)

    async def _claim(self, decide, first: TeamDecision | None = None) -> TeamDecision:
        """Decide (``decide()`` -> TeamDecision) and claim the plan's reservation: publish it, and plan again if
        an earlier claim crosses this one (``mission.team``'s allocation rule, made safe between vehicles: of two
        crossing claims the later one yields; taking frames in turn, every earlier claim is already heard)."""
        assert self.team is not None
        team = self.team
        for attempt in range(CLAIM_ATTEMPTS):
            self._ingest_team()
            self._own_pose_variance()
            decision = first if attempt == 0 and first is not None else decide()
            if decision.plan is None:
                self.decisions.append(decision)
                return decision
            path = decision.plan.path[:, :3]
            var_end = self.brain.var_at_end(team.index, path)
            stamp = team.claim(self.t, path, var_end)
            crossing = team.earlier_crossing(path, stamp, self.brain.team.separation_m, var_end)
            if crossing is None:
                self.decisions.append(decision)
                return decision
            self.event("yield", to=crossing, attempt=attempt)
            team.set(self.t, "hold", self.current()[None, :3])
        return TeamDecision(self.brain.phase, None, "hold: claims kept crossing", vehicle=self.team.index,
                            hold_s=self.brain.team.hold_s)

    def _own_pose_variance(self) -> tuple[float, float]:
        """This vehicle's reported x-y pose variance now and its growth per metre flown (from its frames),
        handed to the team brain for the drift margin of its next path."""
        assert self.team is not None and isinstance(self.brain, TeamBrain)
        p = self.frames.pose_at(self.t) or self.frames.pose()
        f = self.frames.frames()
        var = float(p.var_x) if p is not None and math.isfinite(p.var_x) else 0.0
        density = float(drift_density_from_poses(f.positions, f.pose_variances, f.dwell)[0]) if len(f) > 1 else 0.0
        self.brain.set_pose_variance(self.team.index, var, density)
        return var, density

    async def search(self) -> Decision:
        """The team's search from this vehicle: plans from the team brain (every vehicle's dwells and frames),
        reservations claimed on ``team/status``; returns the final decision (the plan None)."""
        assert self.team is not None and isinstance(self.brain, TeamBrain)
        team, brain, me = self.team, self.brain, self.team.index
        current = self.current()
        team.set(self.t, "start", np.r_[current[:2], self.config.altitude_m][None, :],
                 self._own_pose_variance()[0])
        # no plan before every teammate has said where it is (airborne at its launch point): hover meanwhile
        t0 = self.t
        while len(team.reserved()) < len(team.mates) and self.t - t0 < START_WAIT_SIM_S:
            await self.tick()
        missing = [n for n in team.mates if team.names.index(n) not in team.reserved()]
        if missing:
            self.event("teammates_missing_at_start", vehicles=missing)
        decision = await self._claim(lambda: brain.start(self.current(), me, team.reserved()))
        own_dwells = 0
        while self.abort_reason is None:
            over = team.over()
            if over is not None:  # done too: its teammates no longer take turns with it
                team.finish(self.t, over.reason, decided=False, outcome=over.outcome)
                return over
            if decision.done:
                team.finish(self.t, decision.reason, decided=True, outcome=decision.outcome)
                return decision.as_decision()
            if decision.retire:  # boxed in by the teammates for long: this vehicle leaves, the team goes on
                team.finish(self.t, decision.reason, decided=False, outcome=decision.outcome)
                return decision.as_decision()
            if decision.plan is None:  # hold where it is, then ask again
                here = self.current()
                team.set(self.t, "hold", here[None, :3])
                self.publish_state("hold", decision.reason)
                t_end = self.t + decision.hold_s
                while self.t < t_end - 1e-6 and self.abort_reason is None and team.over() is None:
                    await self.tick()
                decision = await self._claim(lambda: brain.replan(me, self.current(), team.reserved()))
                continue
            self.publish_plan(decision.as_decision())
            plan = decision.plan
            d = await self.upload(plan)
            self.publish_state(decision.phase.value, f"flying to dwell point {own_dwells}: {decision.reason}")
            first_frame = len(self.frames.records)
            if not await self.arrive(d, plan.path_length() + 0.5):
                if self.abort_reason is not None or team.over() is not None:
                    continue
                self.event("leg_timeout", target=d.tolist())
            self.set_dwell(own_dwells)
            team.set(self.t, "dwell", d[None, :3])
            self.publish_state("dwell", f"dwelling at ({d[0]:.2f}, {d[1]:.2f})")
            status = await self.dwell()
            if status is None:
                continue
            position = self.dwelt(d, own_dwells, status)
            records = list(self.frames.records)
            times = [r.t for r in records if r.dwell == own_dwells]
            flown = np.array([(r.x, r.y, r.z) for r in records[first_frame:] if r.dwell < 0]).reshape(-1, 3)
            team.add_dwell(own_dwells, position, status.mean_rate, min(times, default=self.t),
                           max(times, default=self.t), flown)
            self._ingest_team()
            frames = team.frames(self.frames.frames())
            self._own_pose_variance()
            decision = brain.end_dwell(position, status, frames, self.current(), flown, me, team.reserved())
            if decision.plan is not None:  # claim it (and plan again if an earlier claim crosses it)
                decision = await self._claim(lambda: brain.replan(me, self.current(), team.reserved()),
                                             first=decision)
            else:
                self.decisions.append(decision)
            await self.end_dwell(decision)
            own_dwells += 1
        team.finish(self.t, f"search aborted: {self.abort_reason}", decided=False, outcome=Outcome.ABORTED)
        return Decision(Phase.DONE, None, f"search aborted: {self.abort_reason}", Outcome.ABORTED)
