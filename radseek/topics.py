"""Every zenoh key and payload schema of radseek, declared once (like PX4's ``msg/`` files).

Keys live under ``radseek/<vehicle>/``. Payloads are UTF-8 JSON objects so that any third-party
tool (``zenoh-cli``, Foxglove, a ROS bridge) can read them; the raw detector frame is the board's
binary encoding (see ``radseek.board_wire``). Frames: local ENU metres, yaw in radians
counter-clockwise from +x (east); times in simulation seconds from the shared clock.

Topics whose name starts with ``sim/`` carry the simulated world's truth: only the detector
emulator may subscribe to them (RadInterAct-style isolation). Estimators see ``pose`` only.

Usage::

    from radseek import topics
    key = topics.key(topics.HISTOGRAM, vehicle="uav0")      # "radseek/uav0/detector/histogram"
    payload = topics.Histogram(...).to_bytes()
    msg = topics.Histogram.from_bytes(sample.payload.to_bytes())   # raises PayloadError on bad input
"""

from __future__ import annotations

import itertools
import json
import math
import threading
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any, ClassVar, Self

from radseek.outcome import Outcome

PREFIX = "radseek"
DEFAULT_VEHICLE = "uav0"
N_CHANNELS = 32


class PayloadError(ValueError):
    """A message that does not match its declared schema (names the topic and field)."""


def key(topic: str, vehicle: str = DEFAULT_VEHICLE) -> str:
    """Full key expression of ``topic`` for ``vehicle``: ``radseek/<vehicle>/<topic>``."""
    if not vehicle or "/" in vehicle or "*" in vehicle:
        raise ValueError(f"vehicle name {vehicle!r} must be one non-empty key chunk")
    return f"{PREFIX}/{vehicle}/{topic}"


def all_keys(vehicle: str = "*") -> str:
    """Key expression matching every radseek topic (of one vehicle, or all)."""
    return f"{PREFIX}/{vehicle}/**"


# topic names (relative to radseek/<vehicle>/)
SIM_CLOCK = "sim/clock"
SIM_TRUTH_POSE = "sim/truth_pose"
POSE = "pose"
HISTOGRAM = "detector/histogram"
RAW_FRAME = "detector/raw"
DETECTOR_STATUS = "detector/status"
MISSION_STATE = "mission/state"
MISSION_LOCKSTEP = "mission/lockstep"
ESTIMATE = "estimate"
PLAN = "plan"
TEAM_STATUS = "team/status"
#: the key chunk of what belongs to the whole team (``radseek run --vehicles N``) rather than one vehicle:
#: the joint estimate from every vehicle's frames is ``Estimate`` on ``key(ESTIMATE, TEAM)``
TEAM = "team"
#: topics only a team publishes (``radseek run --vehicles N``): a single vehicle's run has none of them
TEAM_ONLY = (TEAM_STATUS,)


@dataclass(frozen=True)
class Rate:
    """How often a key's publisher sends: ``per_sim_s`` samples per sim second plus ``per_wall_s`` per wall
    second (heartbeats kept on wall time); at speed-up s that is ``per_sim_s * s + per_wall_s`` per wall second."""

    per_sim_s: float
    per_wall_s: float = 0.0


#: each key's expected rate (one publisher): a receiver takes a publisher far over it for a flood
#: (``mission.key_accounts``). ``pose``: 10 Hz on the vehicle's step grid, plus one where lockstep holds it;
#: ``detector/status``: 1 Hz of sim time, plus one at once when the detector ends or skips a frame;
#: ``team/status``: on each change (a frame handled at most) and a heartbeat every wall second.
EXPECTED_RATES: dict[str, Rate] = {
    SIM_CLOCK: Rate(50.0),
    SIM_TRUTH_POSE: Rate(20.0),
    POSE: Rate(20.0),
    HISTOGRAM: Rate(10.0),
    RAW_FRAME: Rate(10.0),
    DETECTOR_STATUS: Rate(2.0, 1.0),
    MISSION_STATE: Rate(10.0, 1.0),
    MISSION_LOCKSTEP: Rate(10.0, 2.0),
    ESTIMATE: Rate(10.0, 1.0),
    PLAN: Rate(10.0, 1.0),
    TEAM_STATUS: Rate(10.0, 1.0),
}

# Histogram.flags bits (mirrors the board's status byte, radseek.board_wire)
FLAG_SATURATED = 0x01  # a comparator counter wrapped or the input stage saturated
FLAG_STALE_POSE = 0x02  # no true pose arrived recently: the emulator sent zero counts, do not use
FLAG_GAP = 0x04  # one or more frames were lost before this one (sequence jump)
FLAG_CRC_ERROR = 0x08  # set by a receiver that kept a frame whose CRC failed (normally dropped)

# The board's physical limits (its wire format, radseek.board_wire / docs/frame-format.md): a payload
# outside them cannot have come from the board, so it is rejected like any other schema violation.
COUNT_MAX = 0xFFFF  # u16 per comparator channel and frame
SEQ_MAX = 0xFFFFFFFF  # u32 frame counter
FLAGS_MAX = 0xFF  # u8 status byte
DURATION_MAX_S = 0xFFFFFFFF / 1e6  # u32 microseconds integrated
BOARD_TIME_MAX_S = 0xFFFFFFFFFFFFFFFF / 1e6  # u64 microseconds since power-on
#: sim time (field ``t`` of every payload) lies in [0, SIM_TIME_MAX_S]: 1e7 s is 115 days of flight
SIM_TIME_MAX_S = 1e7
SPEEDUP_MAX = 1e4  # sim seconds per wall second


def _check_number(topic: str, name: str, value: Any, *, finite: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise PayloadError(f"{topic}: field {name!r} must be a number, got {_short(value)}")
    if finite and not math.isfinite(value):
        raise PayloadError(f"{topic}: field {name!r} must be finite, got {value!r}")
    try:
        return float(value)
    except OverflowError:  # an integer too large for a float (10**400)
        raise PayloadError(f"{topic}: field {name!r} is out of range, got {_short(value)}") from None


def _check_range(topic: str, name: str, value: Any, lo: float, hi: float) -> float:
    v = _check_number(topic, name, value)
    if not lo <= v <= hi:
        raise PayloadError(f"{topic}: field {name!r} must be in [{lo:g}, {hi:g}], got {_short(value)}")
    return v


def _check_int(topic: str, name: str, value: Any, lo: int | None = None, hi: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise PayloadError(f"{topic}: field {name!r} must be an integer, got {_short(value)}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise PayloadError(f"{topic}: field {name!r} must be in [{lo}, {hi}], got {_short(value)}")
    return value


def _short(value: Any, limit: int = 60) -> str:
    """repr of a (possibly huge) offending value, cut short for the log."""
    try:
        text = repr(value)
    except ValueError:  # an int with more digits than str() allows
        text = f"<{type(value).__name__} too large to print>"
    return text if len(text) <= limit else text[:limit] + "..."


@dataclass(frozen=True)
class _Payload:
    """Base of all payloads: JSON (de)serialisation with field validation."""

    TOPIC: ClassVar[str] = ""

    def to_dict(self) -> dict[str, Any]:
        """The JSON object: every field, but an optional one (``X | None``) that is None is left out rather than
        sent as null (:func:`json_schema`: a reader that takes one type per field, as Foxglove Studio 1.x does,
        cannot also take null; ``from_dict`` reads an absent field as None)."""
        return {k: v for k, v in asdict(self).items() if v is not None}

    def to_bytes(self) -> bytes:
        return json.dumps(self.to_dict(), separators=(",", ":")).encode()

    @classmethod
    def from_dict(cls, data: Any) -> Self:
        if not isinstance(data, dict):
            raise PayloadError(f"{cls.TOPIC}: payload must be a JSON object, got {type(data).__name__}")
        kwargs = {}
        for f in fields(cls):
            if f.name not in data:
                if f.default is not f.default_factory:  # has a default of either kind
                    continue
                raise PayloadError(f"{cls.TOPIC}: missing field {f.name!r}")
            kwargs[f.name] = data[f.name]
        obj = cls(**kwargs)
        obj.validate()
        return obj

    @classmethod
    def from_bytes(cls, payload: bytes) -> Self:
        try:
            data = json.loads(payload)
        except RecursionError:  # deeply nested arrays/objects: refused, never a traceback
            raise PayloadError(f"{cls.TOPIC}: payload is nested too deeply") from None
        except (UnicodeDecodeError, ValueError) as exc:  # JSONDecodeError, or an int of > 4300 digits
            raise PayloadError(f"{cls.TOPIC}: payload is not JSON ({_short(str(exc), 120)})") from None
        try:
            return cls.from_dict(data)
        except RecursionError:
            raise PayloadError(f"{cls.TOPIC}: payload is nested too deeply") from None

    def validate(self) -> None:
        """Types of every declared field, finiteness of numbers, and sim time ``t`` in range."""
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("float", float):
                _check_number(self.TOPIC, f.name, v)
            elif f.type == "float | None":
                if v is not None:
                    _check_number(self.TOPIC, f.name, v)
            elif f.type in ("int", int):
                _check_int(self.TOPIC, f.name, v)
            elif f.type in ("str", str) and not isinstance(v, str):
                raise PayloadError(f"{self.TOPIC}: field {f.name!r} must be a string, got {_short(v)}")
        if any(f.name == "t" for f in fields(self)):
            _check_range(self.TOPIC, "t", self.t, 0.0, SIM_TIME_MAX_S)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class SimClock(_Payload):
    """``sim/clock``: the one simulation clock every process reads (published by the vehicle)."""

    TOPIC: ClassVar[str] = SIM_CLOCK
    t: float  # s, simulation time since start
    speedup: float  # simulation seconds per wall second (1.0 = real time)

    def validate(self) -> None:
        super().validate()
        if not 0 < self.speedup <= SPEEDUP_MAX:
            raise PayloadError(f"{self.TOPIC}: field 'speedup' must be in (0, {SPEEDUP_MAX:g}], got {self.speedup!r}")


@dataclass(frozen=True)
class TruthPose(_Payload):
    """``sim/truth_pose``: the vehicle's true pose. Simulator only: never read by estimators."""

    TOPIC: ClassVar[str] = SIM_TRUTH_POSE
    t: float  # s, sim time
    x: float  # m, ENU
    y: float
    z: float
    yaw: float  # rad, detector axis heading, CCW from +x


@dataclass(frozen=True)
class Pose(_Payload):
    """``pose``: the vehicle's *estimated* pose with its position covariance (GPS-denied odometry)."""

    TOPIC: ClassVar[str] = POSE
    t: float  # s, sim time
    x: float  # m, ENU, estimated
    y: float
    z: float
    yaw: float  # rad
    var_x: float = 0.0  # m^2, variance of the position estimate
    var_y: float = 0.0
    var_z: float = 0.0
    var_yaw: float = 0.0  # rad^2

    def validate(self) -> None:
        super().validate()
        for name in ("var_x", "var_y", "var_z", "var_yaw"):
            if getattr(self, name) < 0:
                raise PayloadError(f"{self.TOPIC}: field {name!r} must be >= 0")


@dataclass(frozen=True)
class Histogram(_Payload):
    """``detector/histogram``: one decoded 100 ms board frame.

    ``counts[k]`` are pulses whose amplitude fell in comparator channel k (channel 31 = overflow).
    ``board_time`` is the board's own clock (s); ``t`` the sim time at the frame's end;
    ``duration`` the real time integrated. The board reports no live time (dead time loses counts
    silently); ``live_time`` is the emulator's truth and is present only for diagnostics.
    Receivers drop (and count) a histogram outside the board's limits: counts 0..65535 per channel
    (u16), seq u32, flags u8, 0 < duration <= 4295 s (u32 us), 0 <= live_time <= duration; like every
    payload here, its ``t`` must lie in [0, 1e7] s of sim time.
    """

    TOPIC: ClassVar[str] = HISTOGRAM
    seq: int  # board frame counter (u32); a jump means lost frames (FLAG_GAP)
    board_time: float  # s, board clock at the end of the integration
    t: float  # s, sim time at the frame's end
    duration: float  # s, real time integrated (0.1)
    counts: list[int]  # 32 pulse counts, comparator channels 0..31
    flags: int = 0  # FLAG_* bits
    live_time: float | None = None  # s, emulator truth for diagnostics (the board does not report it)
    wall_time: float | None = None  # s, Unix wall time at publication (optional; for latency measurement only)

    @property
    def total(self) -> int:
        return int(sum(self.counts))

    @property
    def rate(self) -> float:
        return self.total / self.duration if self.duration > 0 else 0.0

    def validate(self) -> None:
        """The schema and the board's physical limits: u16 counts, u32 seq and integration time in
        microseconds, u8 flags, u64 board clock; live time within the integration."""
        super().validate()
        _check_range(self.TOPIC, "board_time", self.board_time, 0.0, BOARD_TIME_MAX_S)
        if not 0 < self.duration <= DURATION_MAX_S:
            raise PayloadError(f"{self.TOPIC}: field 'duration' must be in (0, {DURATION_MAX_S:g}] s, "
                               f"got {self.duration!r}")
        _check_int(self.TOPIC, "seq", self.seq, 0, SEQ_MAX)
        _check_int(self.TOPIC, "flags", self.flags, 0, FLAGS_MAX)
        if not isinstance(self.counts, list) or len(self.counts) != N_CHANNELS:
            raise PayloadError(f"{self.TOPIC}: field 'counts' must be a list of {N_CHANNELS} integers")
        for k, c in enumerate(self.counts):
            if isinstance(c, bool) or not isinstance(c, int) or not 0 <= c <= COUNT_MAX:
                raise PayloadError(f"{self.TOPIC}: counts[{k}] must be an integer in [0, {COUNT_MAX}] "
                                   f"(u16 per channel), got {_short(c)}")
        if self.live_time is not None and not 0 <= self.live_time <= self.duration * (1 + 1e-9):
            raise PayloadError(f"{self.TOPIC}: field 'live_time' must be in [0, duration], got {self.live_time!r}")


@dataclass(frozen=True)
class DetectorStatus(_Payload):
    """``detector/status``: 1 Hz health of the detector process (frame and error counters)."""

    TOPIC: ClassVar[str] = DETECTOR_STATUS
    t: float
    frames: int
    stale_frames: int
    crc_errors: int
    state: str = "ok"
    # sim time of the last histogram this process published (None: none yet, or an older sender); with
    # ``t`` (every frame ending by then is handled) the mission tells a frame not sent from one in flight
    last_histogram_t: float | None = None

    def validate(self) -> None:
        super().validate()
        for name in ("frames", "stale_frames", "crc_errors"):
            _check_int(self.TOPIC, name, getattr(self, name), 0)


@dataclass(frozen=True)
class MissionState(_Payload):
    """``mission/state``: what the mission is doing, for displays."""

    TOPIC: ClassVar[str] = MISSION_STATE
    t: float
    phase: str  # e.g. "connect", "takeoff", "explore", "dwell", "transit", "rtl", "done"
    dwell_index: int = -1
    battery: float = 1.0  # remaining fraction
    progress: str = ""


@dataclass(frozen=True)
class MissionLockstep(_Payload):
    """``mission/lockstep``: the mission's side of lockstep (as PX4 SITL has it with its simulator).

    The mission publishes it after it has handled each histogram frame, *after* any MAVLink command it
    sent in response (send first, then ack), and repeats its last state about twice a wall second while
    it computes. A vehicle run with ``--lockstep`` does not step sim time past ``until``: the simulated
    world waits while the mission computes, so a pause costs what it would cost in the air. ``busy``
    means the mission is still working on the frame ending at ``t`` (then ``until == t``); otherwise
    ``until`` is ``t`` plus one frame. ``attached`` false lets the vehicle run free (the mission is done).
    No message for the vehicle's ``--lockstep-timeout`` wall seconds releases lockstep (mission gone)."""

    TOPIC: ClassVar[str] = MISSION_LOCKSTEP
    t: float  # s, sim time up to which the mission has taken every frame
    until: float  # s, sim time the vehicle may step to (t while busy, t + one frame when waiting)
    busy: bool = False  # the mission is computing on the frame ending at t
    attached: bool = True  # False: the mission leaves lockstep, the vehicle runs free

    def validate(self) -> None:
        super().validate()
        _check_range(self.TOPIC, "until", self.until, self.t, SIM_TIME_MAX_S)
        for name in ("busy", "attached"):
            if not isinstance(getattr(self, name), bool):
                raise PayloadError(f"{self.TOPIC}: field {name!r} must be true or false, got "
                                   f"{_short(getattr(self, name))}")


#: the state of one source in an ``estimate``, in the order of its covariance block
ESTIMATE_STATE = ("x", "y", "z", "cps_at_1m")
#: numbers per source in ``Estimate.covariance`` (and ``crlb``): one row-major 4 x 4 block
ESTIMATE_BLOCK = len(ESTIMATE_STATE) ** 2
#: metadata key of an object field (``dict[str, V]``, alone or as a list's items): its keys and their types, as
#: field annotations are written (``{"x": "float", "index": "int"}``). :func:`json_schema` declares them as the
#: object's properties: a schema object must name its properties for Foxglove Studio 1.x to read the channel
KEYS = "keys"


def rows(flat: list[float], width: int) -> list[list[float]]:
    """A flat list of numbers as its rows of ``width`` (``Plan.dwell_points``, ``TeamStatus.reservation``...)."""
    return [list(flat[i:i + width]) for i in range(0, len(flat) - width + 1, width)]


@dataclass(frozen=True)
class Estimate(_Payload):
    """``estimate``: the current source estimate with covariance (and CRLB when known).

    ``covariance`` holds each source's covariance of (x, y, z, cps_at_1m) as one row-major 4 x 4 block, the
    blocks one after the other: 16 numbers per source, source i's at ``covariance[16 i : 16 i + 16]``
    (cross-source terms are not sent). ``crlb`` has the same layout, or is absent when the method has no bound.
    Unknown entries are NaN. The mission's reported source carries the covariance its search decides on and its
    summary reports: misfit-scaled and covering the likelihood's other modes, not the fit's curvature alone.
    """

    TOPIC: ClassVar[str] = ESTIMATE
    t: float
    method: str
    # per source: x, y, z (m, ENU), cps_at_1m (cps)
    sources: list[dict[str, float]] = field(metadata={KEYS: dict.fromkeys(ESTIMATE_STATE, "float")})
    background_cps: float
    covariance: list[float]  # per source in turn: row-major 4 x 4 of (x, y, z, cps_at_1m), 16 numbers
    crlb: list[float] | None = None  # same layout as covariance, or absent

    def validate(self) -> None:
        super().validate()
        if not isinstance(self.sources, list):
            raise PayloadError(f"{self.TOPIC}: field 'sources' must be a list of objects")
        for i, src in enumerate(self.sources):
            if not isinstance(src, dict):
                raise PayloadError(f"{self.TOPIC}: sources[{i}] must be an object with {', '.join(ESTIMATE_STATE)}")
            for name in ESTIMATE_STATE:
                if name not in src:
                    raise PayloadError(f"{self.TOPIC}: sources[{i}] lacks {name!r}")
                _check_number(self.TOPIC, f"sources[{i}].{name}", src[name], finite=False)
        self._check_blocks("covariance", self.covariance)
        if self.crlb is not None:
            self._check_blocks("crlb", self.crlb)

    def _check_blocks(self, name: str, blocks: Any) -> None:
        n = len(self.sources)
        shape = f"{ESTIMATE_BLOCK} numbers (a row-major 4 x 4 block) per source, one list"
        if not isinstance(blocks, list) or len(blocks) != n * ESTIMATE_BLOCK:
            got = f"{len(blocks)} entries" if isinstance(blocks, list) else type(blocks).__name__
            raise PayloadError(f"{self.TOPIC}: field {name!r} must hold {shape}: {n} source(s), got {got}")
        for k, v in enumerate(blocks):
            _check_number(self.TOPIC, f"{name}[{k}]", v, finite=False)

    def covariance_block(self, source: int = 0) -> list[list[float]]:
        """Source ``source``'s covariance of (x, y, z, cps_at_1m) as 4 rows of 4."""
        return rows(self.covariance[ESTIMATE_BLOCK * source:ESTIMATE_BLOCK * (source + 1)], len(ESTIMATE_STATE))


#: the numbers of one point of ``Plan.dwell_points`` and ``Plan.path``, in order
PLAN_POINT = ("x", "y", "z", "yaw")
#: the numbers of one point of ``TeamStatus.reservation`` and ``TeamStatus.flown``, in order
TEAM_POINT = ("x", "y", "z")


def _check_points(topic: str, name: str, flat: Any, point: tuple[str, ...]) -> None:
    """A flat list of points, ``len(point)`` finite numbers each (one list: Foxglove Studio 1.x reads no
    arrays of arrays)."""
    width = len(point)
    shape = f"one list of numbers, ({', '.join(point)}) of each point in turn"
    if not isinstance(flat, list):
        raise PayloadError(f"{topic}: field {name!r} must be {shape}, got {_short(flat)}")
    for k, v in enumerate(flat):
        _check_number(topic, f"{name}[{k}]", v)
    if len(flat) % width:
        raise PayloadError(f"{topic}: field {name!r} must be {shape}: a multiple of {width} numbers, got {len(flat)}")


@dataclass(frozen=True)
class Plan(_Payload):
    """``plan``: the next dwell points and the collision-free path to the first, each a flat list of points
    (x, y, z, yaw): point i at ``[4 i : 4 i + 4]``."""

    TOPIC: ClassVar[str] = PLAN
    t: float
    dwell_points: list[float]  # x, y, z, yaw (m, ENU; rad) of each dwell point in turn
    path: list[float] = field(default_factory=list)  # x, y, z, yaw of each waypoint in turn

    def validate(self) -> None:
        super().validate()
        for name in ("dwell_points", "path"):
            _check_points(self.TOPIC, name, getattr(self, name), PLAN_POINT)

    def points(self, name: str) -> list[list[float]]:
        """``dwell_points`` or ``path`` as a list of (x, y, z, yaw)."""
        return rows(getattr(self, name), len(PLAN_POINT))


#: the keys of each of ``TeamStatus.dwells`` and their types
TEAM_DWELL = {"index": "int", "x": "float", "y": "float", "z": "float", "mean_rate": "float", "t_first": "float",
              "t_last": "float"}

#: what a team member is doing (``TeamStatus.state``)
#: ``takeoff``: the mission runs but has not said where it starts (its reservation means nothing yet)
TEAM_STATES = ("takeoff", "start", "fly", "dwell", "hold", "done")


@dataclass(frozen=True)
class TeamStatus(_Payload):
    """``team/status``: one vehicle's mission to its teammates (paper 004's multi-robot search).

    Sent on every change (a plan, a dwell's start and end, a hold, the end) and about once a wall second in between
    (a heartbeat: a teammate silent for long is taken as failed). ``reservation`` is the airspace the vehicle has
    committed to: (x, y, z) points of the rest of its path, its next dwell point last (one point while it dwells or
    holds), as one flat list (point i at ``[3 i : 3 i + 3]``); teammates keep their separation from it. ``dwells``
    lists every dwell the vehicle has ended, cumulative so that a lost message loses nothing: each {index, x, y, z,
    mean_rate, t_first, t_last} (its own dwell index, the estimated position, the dwell's gross rate in cps, the sim
    times of its first and last frames). ``flown`` samples the path it has flown (x, y, z per point, flat as
    ``reservation``), for the team's explored area. ``reason`` says why the search ended (state ``done``;
    ``outcome`` as a ``radseek.outcome.Outcome`` value), ``decided`` whether this vehicle's estimate ended it (the
    whole team then ends its search). ``var_xy`` is the drift the vehicle expects by its reservation's end (its
    reported pose variance plus its growth over the path): teammates widen the separation by it, since the vehicles
    fly on drifting estimates. ``stamp`` (the sim time of the claim) orders two claims: of two crossing reservations
    the later claim yields and plans again (of two at one time, the higher team index). ``handled_t`` is the last
    frame the sender's mission has fully handled (its decisions on it sent): the team's vehicles take their frames
    in turn on it (``mission.team_link``), so every vehicle decides on what the others said up to a known frame."""

    TOPIC: ClassVar[str] = TEAM_STATUS
    t: float  # s, the sender's sim time
    vehicle: str
    seq: int  # counts the sender's messages
    state: str  # one of TEAM_STATES
    reservation: list[float]  # x, y, z of each point in turn
    dwells: list[dict[str, float]] = field(default_factory=list, metadata={KEYS: TEAM_DWELL})
    flown: list[float] = field(default_factory=list)  # x, y, z of each point in turn
    reason: str = ""
    decided: bool = False
    stamp: float = 0.0  # s, sim time when this reservation was claimed
    var_xy: float = 0.0  # m^2, >= 0: the x-y pose variance (per axis) the vehicle expects at its reservation's end
    outcome: str = ""  # with state done: the ``radseek.outcome.Outcome`` value of ``reason`` ("" before then)
    handled_t: float = -1.0  # s, the last frame the sender's mission has fully handled (-1: none yet)

    def validate(self) -> None:
        super().validate()
        if self.state not in TEAM_STATES:
            raise PayloadError(f"{self.TOPIC}: field 'state' must be one of {TEAM_STATES}, got {_short(self.state)}")
        _check_int(self.TOPIC, "seq", self.seq, 0)
        _check_range(self.TOPIC, "var_xy", self.var_xy, 0.0, 1e6)
        _check_range(self.TOPIC, "handled_t", self.handled_t, -1.0, self.t + 1e-6)
        if not isinstance(self.decided, bool):
            raise PayloadError(f"{self.TOPIC}: field 'decided' must be true or false, got {_short(self.decided)}")
        if not isinstance(self.outcome, str) or self.outcome not in {"", *(o.value for o in Outcome)}:
            raise PayloadError(f"{self.TOPIC}: field 'outcome' must be empty or one of "
                               f"{tuple(o.value for o in Outcome)}, got {_short(self.outcome)}")
        for name in ("reservation", "flown"):
            _check_points(self.TOPIC, name, getattr(self, name), TEAM_POINT)
        if not self.reservation:
            raise PayloadError(f"{self.TOPIC}: field 'reservation' must hold at least one point")
        if not isinstance(self.dwells, list):
            raise PayloadError(f"{self.TOPIC}: field 'dwells' must be a list of objects")
        for i, d in enumerate(self.dwells):
            if not isinstance(d, dict):
                raise PayloadError(f"{self.TOPIC}: dwells[{i}] must be an object")
            _check_int(self.TOPIC, f"dwells[{i}].index", d.get("index"), 0)
            for name in (k for k, kind in TEAM_DWELL.items() if kind == "float"):
                if name not in d:
                    raise PayloadError(f"{self.TOPIC}: dwells[{i}] lacks {name!r}")
                _check_number(self.TOPIC, f"dwells[{i}].{name}", d[name])

    def points(self, name: str) -> list[list[float]]:
        """``reservation`` or ``flown`` as a list of (x, y, z)."""
        return rows(getattr(self, name), len(TEAM_POINT))


PAYLOADS: dict[str, type[_Payload]] = {
    cls.TOPIC: cls
    for cls in (SimClock, TruthPose, Pose, Histogram, DetectorStatus, MissionState, MissionLockstep,
                Estimate, Plan, TeamStatus)
}


_SCALARS = {"float": {"type": "number"}, "int": {"type": "integer"}, "str": {"type": "string"},
            "bool": {"type": "boolean"}}


def _type_schema(type_text: str, keys: dict[str, str] | None, where: str) -> dict[str, Any]:
    """JSON schema of a field annotation (as text: the module uses postponed annotations) in the one form that
    both ``jsonschema`` and Foxglove Studio 1.x's JSON-schema reader take: one ``type`` per value, objects with
    their ``properties``, arrays of scalars or of objects (docs/vehicle.md, "What Studio 1.48 reads")."""
    t = type_text.replace(" ", "")
    if t.endswith("|None"):  # absent when None (_Payload.to_dict): the value, when there, is an X
        return _type_schema(t.removesuffix("|None"), keys, where)
    if t.startswith("list["):
        items = _type_schema(t[5:-1], keys, where)
        if items["type"] == "array":
            raise TypeError(f"{where}: an array of arrays ({type_text}): send one flat list (see Plan)")
        return {"type": "array", "items": items}
    if t.startswith("dict["):
        if not keys:
            raise TypeError(f"{where}: an object with no declared keys ({type_text}): give field(metadata={{KEYS: "
                            "...}})")
        return {"type": "object", "properties": {k: _type_schema(v, None, f"{where}.{k}") for k, v in keys.items()},
                "required": list(keys)}
    if t not in _SCALARS:
        raise TypeError(f"{where}: no JSON schema for {type_text}")
    return dict(_SCALARS[t])


def json_schema(cls: type[_Payload]) -> dict[str, Any]:
    """JSON schema (draft 2020-12) of a payload class, generated from its declaration: every field a property of
    its type, the fields without a default required (``from_dict`` requires them); an optional field
    (``X | None``) is absent when None, never null. The MCAP log (``radseek_io.mcap_log``) and the live view
    (``radseek view``) give it to Foxglove."""
    props = {f.name: _type_schema(str(f.type), f.metadata.get(KEYS), f"{cls.__name__}.{f.name}")
             for f in fields(cls)}
    required = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING]
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": cls.__name__, "type": "object",
            "properties": props, "required": required, "description": " ".join((cls.__doc__ or "").split())}


#: schema name of the raw board frame (docs/frame-format.md; decoded by radseek.board_wire)
RAW_FRAME_SCHEMA = "radseek.BoardFrame"


def encoding(topic: str) -> str:
    """The zenoh encoding a topic's samples carry, MIME type and schema name: ``application/json;radseek.<Payload>``
    for the JSON payloads above, ``application/octet-stream;radseek.BoardFrame`` for the raw frames. Subscribers
    (zenoh-cli, Foxglove's zenoh bridge, a ground station) can tell JSON from binary without knowing radseek."""
    if topic == RAW_FRAME:
        return f"application/octet-stream;{RAW_FRAME_SCHEMA}"
    if topic in PAYLOADS:
        return f"application/json;{PREFIX}.{PAYLOADS[topic].__name__}"
    raise KeyError(f"{topic!r} is not a radseek topic")


class StampedPublisher:
    """A zenoh publisher whose every ``put`` carries ``source_info`` (its entity id and a sequence number 1, 2,
    3...), so a receiver can tell its samples from another publisher's on the same key and a copy of its id from
    itself (``mission.key_accounts``: rate accounting per publisher; a repeated or backward sequence number is a
    forgery). Puts from several threads go out one at a time, in sequence order. Anything else is the zenoh
    publisher's own."""

    def __init__(self, publisher: Any):
        import zenoh

        self._pub = publisher
        self._sn = itertools.count(1)
        self._info = zenoh.SourceInfo  # looked up once: put is on every 10 Hz stream's path
        self._lock = threading.Lock()

    def put(self, payload: Any, **kwargs: Any) -> None:
        with self._lock:  # numbered and sent together: a receiver sees the numbers in order
            self._pub.put(payload, source_info=self._info(self._pub.id, next(self._sn)), **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._pub, name)


def declare_publisher(session: Any, topic: str, vehicle: str = DEFAULT_VEHICLE) -> StampedPublisher:
    """``session.declare_publisher`` for ``key(topic, vehicle)`` with the topic's :func:`encoding`, stamping its
    samples with its id (:class:`StampedPublisher`)."""
    import zenoh

    return StampedPublisher(session.declare_publisher(key(topic, vehicle), encoding=zenoh.Encoding(encoding(topic))))


def topic_of(full_key: str) -> str:
    """The topic name of a full key: ``radseek/uav0/detector/histogram`` -> ``detector/histogram``."""
    parts = full_key.split("/", 2)
    if len(parts) < 3 or parts[0] != PREFIX:
        raise ValueError(f"{full_key!r} is not a radseek key")
    return parts[2]
