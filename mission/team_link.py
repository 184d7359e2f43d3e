"""What one vehicle of a team says and hears (``mission.team_executive.TeamLink``), whatever carries it.

This vehicle's status (``topics.TeamStatus``: where it is, the path it reserved, its dwells and the path it
flew, whether it is done and why) and the rules on the teammates' statuses (their reservations, the earlier
crossing claim, the team's end, their new dwells, the team's frames) are written once here. A carrier says
how a status goes out (``_send``), what the teammates said last (``_statuses``), a teammate's frames
(``_mate_frames``), which teammates are gone (``_gone``) and how to wait for one's turn (``wait_turn``): zenoh
between mission processes (``mission.mission_process._Team``) or shared memory in one process
(``launch.offline_team``).

**Turns.** The vehicles take their frames in turn: vehicle ``i`` takes its next frame (ending at ``t``) only
once every teammate before it in the team (``j < i``) has fully handled its frame ending at ``t``, and every
teammate after it has handled the frame before (``handled_t``, said in each status). So while ``i`` handles
its frame ``t`` it has heard exactly what each teammate said up to its own turn on ``t`` (``j < i``) or on
``t`` minus a frame (``j > i``), over zenoh as in one process, and the same seed flies the same team flight.
A claim is then checked against every earlier claim at once: claims are stamped with their sim time, and
of two at one time the later in the turn yields (``earlier_crossing``).
"""

from __future__ import annotations

import math

import numpy as np

from mission.search import Decision, Phase, SearchBrain
from mission.team import team_frames
from planner.allocation import Reservation, path_clear
from radseek import topics
from radseek.dataset import Frames
from radseek.outcome import Outcome, parse_outcome


def label_dwells(frames: Frames, dwells: list[dict]) -> Frames:
    """``frames`` of a teammate labelled with the dwell index of each announced dwell (its ``t_first`` ..
    ``t_last``), -1 elsewhere: what the teammate's frames say about its dwells as far as it has told."""
    dwell = np.full(len(frames), -1)
    for d in dwells:
        dwell[(frames.t >= d["t_first"] - 1e-6) & (frames.t <= d["t_last"] + 1e-6)] = int(d["index"])
    frames.dwell[:] = dwell
    return frames


class TeamLinkBase:
    """This vehicle's status and the team rules on the teammates' (see the module's docstring)."""

    def __init__(self, me: str, names: tuple[str, ...]):
        if me not in names:
            raise ValueError(f"vehicle {me!r} is not one of the team {names}")
        self.me, self.names, self.index = me, tuple(names), tuple(names).index(me)
        self.mates: dict = {n: None for n in names if n != me}
        self.seq = 0
        self.state = "takeoff"  # until the executive says where it starts (``set(t, "start", ...)``)
        self.reservation = np.zeros((1, 3))
        self.var_xy = 0.0
        self.stamp = 0.0
        self.dwells: list[dict[str, float]] = []
        self.flown = np.zeros((0, 3))
        self.reason = ""
        self.outcome: Outcome | None = None
        self.decided = False
        self.t = 0.0
        self.handled_t = -1.0  # the last frame this vehicle's mission has fully handled
        self._taken = {n: 0 for n in self.mates}  # teammates' dwells already handed to the brain
        self._flown_taken = {n: 0 for n in self.mates}

    # -- the carrier's part
    def _send(self, msg: topics.TeamStatus) -> None:
        raise NotImplementedError

    def _statuses(self) -> dict[str, topics.TeamStatus]:
        """The teammates' last statuses by name (those heard from)."""
        raise NotImplementedError

    def _mate_frames(self, name: str) -> Frames | None:
        raise NotImplementedError

    def _gone(self, name: str) -> bool:
        """A teammate no longer waited for (failed, killed, silent)."""
        raise NotImplementedError

    async def wait_turn(self, t_next: float, frame_s: float) -> None:
        """Until ``turn_ready(t_next, frame_s)``."""
        raise NotImplementedError

    def lost(self) -> list[str]:
        """Teammates taken as failed so far."""
        return []

    # -- turns
    def done_with(self, t: float) -> None:
        """This vehicle's mission has fully handled its frame ending at ``t``: say so (its teammates' turn)."""
        self.t = max(self.t, float(t))
        self.handled_t = float(t)
        self._put()

    def turn_ready(self, t_next: float, frame_s: float) -> bool:
        """May this vehicle take its frame ending at ``t_next``: has every teammate before it handled its frame
        ending at ``t_next``, and every one after it the frame before (a teammate done or gone is not waited for)?"""
        statuses = self._statuses()
        for n in self.mates:
            if self._gone(n):
                continue
            st = statuses.get(n)
            if st is not None and st.state == "done":
                continue
            need = t_next if self.names.index(n) < self.index else t_next - frame_s
            if st is None or st.handled_t < need - 1e-6:
                return False
        return True

    # -- saying
    def status(self) -> topics.TeamStatus:
        return topics.TeamStatus(t=self.t, vehicle=self.me, seq=self.seq, state=self.state,
                                 reservation=self.reservation.ravel().tolist(), dwells=self.dwells,
                                 flown=self.flown[::4].ravel().tolist(), reason=self.reason, decided=self.decided,
                                 stamp=self.stamp, var_xy=self.var_xy, outcome=self.outcome or "",
                                 handled_t=self.handled_t)

    def _put(self) -> None:
        msg = self.status()
        self.seq += 1
        self._send(msg)

    def set(self, t: float, state: str, reservation: np.ndarray, var_xy: float | None = None) -> None:
        self.t, self.state = float(t), state
        self.reservation = np.asarray(reservation, dtype=float).reshape(-1, 3)
        if var_xy is not None:
            self.var_xy = max(float(var_xy), 0.0)
        self._put()

    def claim(self, t: float, path: np.ndarray, var_xy: float) -> float:
        """Announce the plan's path as this vehicle's reservation; returns the claim's stamp (its sim time)."""
        self.stamp = float(t)
        self.set(t, "fly", path, var_xy)
        return self.stamp

    def add_dwell(self, index: int, position: np.ndarray, mean_rate: float, t_first: float, t_last: float,
                  flown: np.ndarray) -> None:
        rate = float(mean_rate) if math.isfinite(mean_rate) else 0.0
        self.dwells.append({"index": int(index), "x": float(position[0]), "y": float(position[1]),
                            "z": float(position[2]), "mean_rate": rate, "t_first": float(t_first),
                            "t_last": float(t_last)})
        if len(flown):
            self.flown = np.vstack([self.flown, flown])

    def finish(self, t: float, reason: str, decided: bool, outcome: Outcome | None = None) -> None:
        self.reason, self.decided, self.outcome = reason, decided, outcome
        self.set(t, "done", self.reservation[-1:])

    # -- what the teammates say
    def reserved(self) -> dict[int, Reservation]:
        """Every teammate's last reservation by team index (a failed teammate's stays: where it was last); a
        teammate still taking off has said none yet."""
        return {self.names.index(n): Reservation(np.asarray(st.points("reservation"), dtype=float), st.var_xy)
                for n, st in self._statuses().items() if st.state != "takeoff"}

    def earlier_crossing(self, path: np.ndarray, stamp: float, separation: float, var_xy: float) -> str | None:
        """A teammate whose reservation crosses ``path`` and was claimed before ``stamp`` (this claim yields)."""
        for n, st in self._statuses().items():
            mate = Reservation(np.asarray(st.points("reservation"), dtype=float), st.var_xy)
            if st.state == "fly" and (st.stamp, self.names.index(n)) < (stamp, self.index) and \
                    not path_clear(path, [mate], separation, var_xy):
                return n
        return None

    def over(self) -> Decision | None:
        """The team's search's end (the teammate's reason and outcome), when a teammate's estimate ended it."""
        for n, st in self._statuses().items():
            if st.state == "done" and st.decided:
                return Decision(Phase.DONE, None, f"{st.reason} (decided by {n})", parse_outcome(st.outcome))
        return None

    def new_dwells(self) -> list[tuple[int, dict, np.ndarray | None]]:
        """Teammates' dwells not yet handed to the brain, with the path each flew since its last."""
        out = []
        for n, st in self._statuses().items():
            new = st.dwells[self._taken[n]:]
            if not new:
                continue
            self._taken[n] = len(st.dwells)
            flown = np.asarray(st.points("flown"), dtype=float).reshape(-1, 3)
            path, self._flown_taken[n] = flown[self._flown_taken[n]:], len(flown)
            for k, d in enumerate(new):
                out.append((self.names.index(n), d, path if k == 0 else None))
        return out

    def frames(self, own: Frames) -> Frames:
        """The team's frames (``mission.team.team_frames``): this vehicle's and every teammate's so far."""
        return team_frames([own if n == self.me else self._mate_frames(n) for n in self.names])

    def summary(self, brain: SearchBrain, own: Frames) -> dict:
        step = np.linalg.norm(np.diff(own.positions, axis=0), axis=1) if len(own) > 1 else np.zeros(0)
        moving = own.dwell[1:] < 0 if len(own) > 1 else np.zeros(0, dtype=bool)
        return {"vehicle": self.me, "team": list(self.names), "decided": self.decided,
                "distance_m": float(step[moving].sum()),
                # one dwell count everywhere: this vehicle's ended dwells, as the team's summary.json and report
                # count them; the joint count it knew of when it stopped is team_dwell_points (a teammate's last
                # dwell may end after this vehicle stopped: it said 4 where the team's summary said 5)
                "dwell_points": len(self.dwells), "own_dwell_points": len(self.dwells),
                "team_dwell_points": len(brain.history),
                # likewise its own search dwells (the executive's search_dwell_points is the joint brain's count)
                "search_dwell_points": brain.search_dwelled_by.count(self.index),
                "team_search_dwell_points": int(brain.search_dwells),
                "teammates_lost": self.lost()}
