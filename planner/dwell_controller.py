"""Automated dwell time (paper 003 sec. III-E): decide when a hover has counted long enough.

Paper 003 sec. III-E: the system "calculates the derivative of the mean of the signal y and considers
T_D^k sufficient once dy/dt < y_thres over a duration t_D^thres > t_D^min", so that the robot dwells
"for a short period of time at areas of decreased radiation intensity (and therefore small variance)
and longer times in the presence of stronger fields".

``DwellController`` is a pure state machine fed one histogram frame at a time (sim time only, no I/O):

* the dwell clock is the summed ``duration`` of frames usable as a rate (``radseek.frame_record.usable_rate``):
  stale-pose, CRC-error and saturated frames are not counted (neither counts nor time), and a ``FLAG_GAP``
  frame is counted but the lost frames before it add no time, so a gap pauses the timer instead of
  inflating it;
* the running mean rate is m = N / T (N counts, T dwell-clock time); its derivative is the slope of m
  over the last ``deriv_lag_s`` of dwell-clock time, dm/dt = (m(T) - m(T - L)) / L;
* the threshold is y_thres = max(deriv_threshold_cps_per_s, k_sigma * sigma_m / t_thres) with
  sigma_m = sqrt(N) / T the Poisson standard error of the current mean. The absolute term is the
  paper's y_thres: since the Poisson noise of dm/dt grows like sqrt(m), a fixed threshold makes
  stronger fields dwell longer (T ~ sqrt(m / L) / y_thres). The Poisson-scaled term stops that growth
  once the mean has settled to within k_sigma standard errors per t_thres, so hot spots do not
  consume the battery (a threshold proportional to sqrt(m) alone would make T independent of m);
* the dwell is sufficient when dm/dt has stayed below y_thres for ``t_thres`` of dwell-clock time and
  T >= ``t_min``; it is cut at T = ``t_max``, or at ``t_timeout`` of elapsed sim time (e.g. a stream of
  stale frames).

Output (``DwellStatus``): the mean rate lambda_k (gross, background not removed), its Poisson standard
deviation sqrt(N) / T, the frames used and rejected.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from radseek.frame_record import usable_rate
from radseek.topics import Histogram


@dataclass(frozen=True)
class DwellConfig:
    """Dwell-time rule settings (paper 003 sec. III-E: the paper's dwells lasted 5-15 s)."""

    t_min: float = 5.0  # s of dwell clock, >= 0: never stop before this
    t_max: float = 15.0  # s of dwell clock, >= t_min: always stop here
    t_thres: float = 2.0  # s, > 0: how long dm/dt must stay below the threshold
    deriv_threshold_cps_per_s: float = 2.0  # cps/s, > 0: the paper's absolute y_thres
    k_sigma: float = 0.6  # >= 0: Poisson-scaled threshold, in standard errors of the mean per t_thres
    deriv_lag_s: float = 1.0  # s, > 0: lag of the running-mean slope
    t_timeout: float = 60.0  # s of elapsed sim time, >= t_max: give up waiting for usable frames

    def __post_init__(self) -> None:
        if not (0 <= self.t_min <= self.t_max):
            raise ValueError("need 0 <= t_min <= t_max")
        if self.t_thres <= 0 or self.deriv_threshold_cps_per_s <= 0 or self.deriv_lag_s <= 0:
            raise ValueError("t_thres, deriv_threshold_cps_per_s and deriv_lag_s must be > 0")
        if self.k_sigma < 0:
            raise ValueError("k_sigma must be >= 0")
        if self.t_timeout < self.t_max:
            raise ValueError("t_timeout must be >= t_max")


@dataclass(frozen=True)
class DwellStatus:
    """The controller's answer after each frame."""

    done: bool
    reason: str  # "running", "converged", "t_max", "timeout"
    mean_rate: float  # cps, lambda_k = N / T (gross: background not subtracted); nan before any usable frame
    sigma_rate: float  # cps, Poisson standard deviation sqrt(N) / T of mean_rate
    counts: int  # N, counts in usable frames
    live_time: float  # s, T: summed duration of usable frames (the dwell clock)
    elapsed: float  # s of sim time since the first frame's start
    frames_used: int
    frames_rejected: int
    derivative: float  # cps/s, latest dm/dt (nan until deriv_lag_s of dwell clock has passed)
    threshold: float  # cps/s, current y_thres
    below_for: float  # s of dwell clock that dm/dt has stayed below y_thres


class DwellController:
    """Feed frames of one dwell with ``update``; start a new dwell with ``reset`` (or a new object)."""

    def __init__(self, config: DwellConfig | None = None):
        self.config = config or DwellConfig()
        self.reset()

    def reset(self) -> None:
        self._n = 0
        self._t_live = 0.0
        self._t_start: float | None = None
        self._used = 0
        self._rejected = 0
        self._below_for = 0.0
        self._history: deque[tuple[float, float]] = deque()  # (live time, running mean) within the lag
        self._last: DwellStatus | None = None
        self._deriv = math.nan

    @property
    def status(self) -> DwellStatus | None:
        return self._last

    def update(self, t: float, counts_total: int, duration: float, flags: int = 0) -> DwellStatus:
        """One frame: ``t`` sim time at the frame's end (s), its total counts, duration (s) and flags."""
        cfg = self.config
        if self._last is not None and self._last.done:
            return self._last  # a finished dwell stays finished until reset()
        if duration <= 0:
            raise ValueError("duration must be > 0")
        if self._t_start is None:
            self._t_start = t - duration
        elapsed = t - self._t_start
        if not usable_rate(flags):
            self._rejected += 1
        else:
            # FLAG_GAP frames are valid: the lost frames before them simply add no dwell-clock time
            self._used += 1
            self._n += int(counts_total)
            prev_t = self._t_live
            self._t_live += duration
            mean = self._n / self._t_live
            self._history.append((self._t_live, mean))
            # keep the newest entry at least deriv_lag_s older than now as the slope's base point
            while len(self._history) >= 2 and self._t_live - self._history[1][0] >= cfg.deriv_lag_s:
                self._history.popleft()
            t0, m0 = self._history[0]
            self._deriv = (mean - m0) / (self._t_live - t0) if self._t_live - t0 >= cfg.deriv_lag_s else math.nan
            if math.isfinite(self._deriv) and abs(self._deriv) < self._threshold():
                self._below_for += self._t_live - prev_t
            else:
                self._below_for = 0.0
        return self._finish(elapsed)

    def update_histogram(self, msg: Histogram) -> DwellStatus:
        """``update`` from a decoded ``detector/histogram`` message (all 32 channels summed)."""
        return self.update(msg.t, msg.total, msg.duration, msg.flags)

    def _threshold(self) -> float:
        cfg = self.config
        if self._t_live <= 0:
            return cfg.deriv_threshold_cps_per_s
        sigma_m = math.sqrt(self._n) / self._t_live
        return max(cfg.deriv_threshold_cps_per_s, cfg.k_sigma * sigma_m / cfg.t_thres)

    def _finish(self, elapsed: float) -> DwellStatus:
        cfg = self.config
        live = self._t_live
        if live >= cfg.t_min - 1e-9 and self._below_for >= cfg.t_thres - 1e-9:
            done, reason = True, "converged"
        elif live >= cfg.t_max - 1e-9:
            done, reason = True, "t_max"
        elif elapsed >= cfg.t_timeout - 1e-9:
            done, reason = True, "timeout"
        else:
            done, reason = False, "running"
        mean = self._n / live if live > 0 else math.nan
        sigma = math.sqrt(self._n) / live if live > 0 else math.nan
        self._last = DwellStatus(
            done=done, reason=reason, mean_rate=mean, sigma_rate=sigma, counts=self._n, live_time=live,
            elapsed=elapsed, frames_used=self._used, frames_rejected=self._rejected,
            derivative=self._deriv, threshold=self._threshold(), below_for=self._below_for,
        )
        return self._last
