"""Per-key, per-publisher rate accounting of the samples a mission subscribes to: a flood is dropped and named.

An authenticated process can still flood its own keys (a board sending histograms at 1 kHz, a vehicle re-sending
poses), and on an open network anyone can. Each subscribed key has an expected rate from its contract
(``radseek.topics.EXPECTED_RATES``, per sim second and per wall second); at the run's speed-up that is
``expected`` samples per wall second. Each publisher of a key (the zenoh entity in ``sample.source_info``, which
radseek's own publishers stamp; "unknown publisher" for a sample without it) gets a token bucket of
``FLOOD_FACTOR x expected`` per wall second with ``BURST_WALL_S`` of burst: a sample over it is dropped before it
is decoded (cheaply) and counted as a flood, so one flooding publisher cannot starve the key's honest one. A
one-line warning names the key, the publisher, the observed and the expected rate, at most every
``WARN_EVERY_WALL_S`` per key and publisher.

Every key has one publisher by contract, so a key's samples are taken from one publisher at a time, its *owner*:
the first publisher heard within its rate. Samples of another publisher while the owner speaks are dropped as
``foreign`` (a forgery, or a second board on one key), named the same way; an owner silent for
``OWNER_SILENT_WALL_S`` hands the key to the next new publisher heard (a restarted detector): one first heard
after the owner's last sample. A publisher already refused while the owner spoke never takes the key over, so a
flooder cannot wait out the owner's pauses (a detector sends no histogram while lockstep holds sim time for a fit).

A forger may also copy the owner's id into its own samples' ``source_info`` (zenoh lets a publisher give any).
radseek's publishers number their samples 1, 2, 3... (``topics.StampedPublisher``, in order per publisher as
zenoh delivers them), so a copy that repeats a number already taken, or goes back, is dropped as
``sequence`` and named "forged (sequence)". A forger that numbers ahead of the owner, or whose copy gets here
first (a router passes a sample to its subscribers one after the other: under load the forger may hear it and
have its copy routed before this subscriber's turn), gets its copy taken and the owner's own sample of that number
dropped: that still names the forgery, and only the router's authentication keeps it out.

``counts()`` gives per key the accepted, flood-dropped, foreign, sequence and invalid samples, and
``dropped_from``: the same per publisher that had any dropped, for ``mission_summary.json``::

    accounts = KeyAccounts(log, speedup=20.0)
    pose = accounts.decode(topics.Pose, sample)   # None: a flood or an invalid payload (counted, maybe logged)
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

from radseek import topics
from radseek.payload_drops import worth_reporting

T = TypeVar("T")

FLOOD_FACTOR = 5.0  # a publisher may send up to this many times its key's expected rate
BURST_WALL_S = 2.0  # wall seconds of samples at that rate a publisher may send at once
MIN_BURST = 20.0  # samples a publisher may always send at once (a slow key's startup, a reconnect's backlog)
WARN_EVERY_WALL_S = 5.0  # a flooded key and publisher is named at most this often
UNKNOWN_PUBLISHER = "unknown publisher"
OWNER_SILENT_WALL_S = 3.0  # wall s of silence after which a key's publisher is replaced by the next one heard
DROP_KINDS = ("flood", "foreign", "sequence", "invalid")
SPEEDUP_WINDOW_WALL_S = 1.0  # wall s over which a clock-following account measures the vehicle's speed-up


def sequence_of(sample: Any) -> int | None:
    """The publisher's sequence number of ``sample`` (``source_info.source_sn``), None without one."""
    info = getattr(sample, "source_info", None)
    sn = getattr(info, "source_sn", None) if info is not None else None
    return sn if isinstance(sn, int) else None


def publisher_of(sample: Any) -> str:
    """The zenoh entity that published ``sample`` (``<zid>/<entity id>``), or ``UNKNOWN_PUBLISHER``: zenoh sets
    ``source_info`` only where the publisher gives it (radseek's own publishers do: ``topics.declare_publisher``)."""
    info = getattr(sample, "source_info", None)
    source = getattr(info, "source_id", None) if info is not None else None
    if source is None:
        return UNKNOWN_PUBLISHER
    return f"{source.zid}/{source.eid}"


@dataclass
class _Bucket:
    """One publisher of one key: its token bucket and its arrivals since the last warning."""

    tokens: float
    refilled: float  # wall time of the last refill
    since: float  # wall time of its first sample
    arrived: int = 0
    last_sn: int = 0  # the highest sequence number (``source_info.source_sn``) taken from it
    #: its samples dropped, per kind ("flood", "foreign", "sequence", "invalid")
    dropped: dict[str, int] = field(default_factory=dict)
    #: per kind of warning ("flood", "foreign"): the wall time and the arrivals at its last line
    warned: dict[str, tuple[float, int]] = field(default_factory=dict)

    def rate_since(self, kind: str, now: float) -> str:
        """Its samples per wall second since its last ``kind`` warning (its first sample for the first)."""
        t0, n0 = self.warned.get(kind, (self.since, 0))
        n, dt = self.arrived - n0, now - t0
        return f"{n / dt:.0f} samples/s observed" if dt >= 0.01 else f"{n} samples at once observed"


@dataclass
class _Key:
    topic: str
    accepted: int = 0
    owner: str | None = None  # the publisher whose samples are taken
    owner_heard: float = 0.0  # wall time of the owner's last sample taken
    buckets: dict[str, _Bucket] = field(default_factory=dict)

    def dropped(self, kind: str) -> int:
        """Its samples dropped as ``kind``, from every publisher (the buckets count them)."""
        return sum(b.dropped.get(kind, 0) for b in self.buckets.values())


class KeyAccounts:
    """The accounting of every key one mission subscribes to (thread-safe: zenoh calls from its own threads)."""

    def __init__(self, logger: logging.Logger, speedup: float | None = 1.0, *,
                 clock: Callable[[], float] = time.monotonic, invalid_first: int = 10):
        if speedup is not None and not speedup > 0:
            raise ValueError(f"speedup must be > 0, got {speedup!r}")
        self._log = logger
        #: None given: follow the vehicle's clock (``observe_sim_time``), from 1 up to the fastest rate measured
        self.follows_clock = speedup is None
        self.speedup = 1.0 if speedup is None else float(speedup)
        self._sim_ref: tuple[float, float] | None = None  # (wall, sim) where the current measuring window began
        self._clock = clock
        self._first = invalid_first
        self._lock = threading.Lock()
        self._keys: dict[str, _Key] = {}

    def observe_sim_time(self, t_sim: float) -> None:
        """A sim time the vehicle's clock gave (an accepted pose's ``t``). Following the clock, the speed-up is
        the fastest sim-per-wall rate measured over ``SPEEDUP_WINDOW_WALL_S`` windows: a mission started by hand
        without ``--speedup`` beside a vehicle at ``--speedup 10`` dropped half its histograms as a flood. Only the
        key's owner's poses get here, so a flooder cannot raise it; a lockstep hold (rate 0) never lowers it."""
        if not self.follows_clock:
            return
        now = self._clock()
        with self._lock:
            if self._sim_ref is None or t_sim < self._sim_ref[1]:
                self._sim_ref = (now, t_sim)
                return
            wall = now - self._sim_ref[0]
            if wall < SPEEDUP_WINDOW_WALL_S:
                return
            rate = (t_sim - self._sim_ref[1]) / wall
            self._sim_ref = (now, t_sim)
            if rate <= self.speedup * 1.1:  # within the measuring noise of the rate already followed
                return
            self.speedup = min(rate, topics.SPEEDUP_MAX)
        self._log.info("following the vehicle's clock: x%.3g speed-up measured, the keys' expected rates with it",
                       self.speedup)

    def expected_wall_hz(self, topic: str) -> float:
        """Samples per wall second the contract of ``topic`` expects at this speed-up."""
        rate = topics.EXPECTED_RATES[topic]
        return rate.per_sim_s * self.speedup + rate.per_wall_s

    def admit(self, sample: Any) -> bool:
        """Whether ``sample`` is taken: from its key's owner, within its rate, its sequence number after the last
        taken (False: dropped as a flood, as foreign or as a forged sequence, counted)."""
        key = str(sample.key_expr)
        publisher = publisher_of(sample)
        sn = sequence_of(sample) if publisher != UNKNOWN_PUBLISHER else None
        now = self._clock()
        warn: tuple | None = None
        with self._lock:
            acct = self._keys.get(key)
            if acct is None:
                acct = self._keys[key] = _Key(topics.topic_of(key))
            limit = FLOOD_FACTOR * self.expected_wall_hz(acct.topic)
            burst = max(MIN_BURST, limit * BURST_WALL_S)
            b = acct.buckets.get(publisher)
            if b is None:
                b = acct.buckets[publisher] = _Bucket(tokens=burst, refilled=now, since=now)
            b.tokens = min(burst, b.tokens + (now - b.refilled) * limit)
            b.refilled = now
            b.arrived += 1
            if b.tokens < 1.0:
                kind = "flood"
            else:
                b.tokens -= 1.0
                owner = acct.owner is None or acct.owner == publisher or (
                    now - acct.owner_heard > OWNER_SILENT_WALL_S and b.since > acct.owner_heard)
                if not owner:
                    kind = "foreign"
                elif sn is not None and sn <= b.last_sn:
                    kind = "sequence"
                else:
                    acct.owner, acct.owner_heard = publisher, now
                    b.last_sn = sn if sn is not None else b.last_sn
                    return True
            b.dropped[kind] = b.dropped.get(kind, 0) + 1
            if kind not in b.warned or now - b.warned[kind][0] >= WARN_EVERY_WALL_S:
                so_far = acct.dropped(kind)
                if kind == "flood":
                    warn = ("flood on %s from %s: %s, %.4g/s expected (x%g speed-up); the excess is dropped "
                            "(%d so far on this key)", key, publisher, b.rate_since(kind, now),
                            self.expected_wall_hz(acct.topic), self.speedup, so_far)
                elif kind == "foreign":
                    warn = ("second publisher on %s: %s (%s) while %s publishes it; its samples are dropped as "
                            "forged (%d so far on this key)", key, publisher, b.rate_since(kind, now), acct.owner,
                            so_far)
                else:
                    warn = ("forged (sequence) on %s from %s: sequence number %d after %d already taken from it "
                            "(a copy of its id); dropped (%d so far on this key)", key, publisher, sn, b.last_sn,
                            so_far)
                b.warned[kind] = (now, b.arrived)
        if warn is not None:
            self._log.warning(*warn)
        return False

    def decode(self, schema: type[T], sample: Any) -> T | None:
        """``schema.from_bytes`` of an admitted sample's payload; None for a flood or an invalid payload (each
        counted on its key; an invalid one logged, naming the key, the first few times and every 100th)."""
        if not self.admit(sample):
            return None
        key = str(sample.key_expr)
        try:
            msg = schema.from_bytes(sample.payload.to_bytes())  # type: ignore[attr-defined]
        except topics.PayloadError as exc:
            with self._lock:
                acct = self._keys[key]
                b = acct.buckets[publisher_of(sample)]
                b.dropped["invalid"] = b.dropped.get("invalid", 0) + 1
                n = acct.dropped("invalid")
            if worth_reporting(n, self._first, 100):
                self._log.warning("dropped invalid sample #%d on %s from %s: %s", n, key, publisher_of(sample), exc)
            return None
        with self._lock:
            self._keys[key].accepted += 1
        return msg

    @property
    def invalid(self) -> int:
        """Invalid samples on every key."""
        with self._lock:
            return sum(a.dropped("invalid") for a in self._keys.values())

    def counts(self) -> dict[str, dict[str, Any]]:
        """Per key heard: ``accepted``, ``flood`` (dropped over the rate), ``foreign`` (dropped: not the key's
        publisher), ``sequence`` (dropped: a sequence number repeated or going back) and ``invalid`` samples;
        with any dropped, ``dropped_from``: per publisher, its dropped samples of each kind."""
        with self._lock:
            out: dict[str, dict[str, Any]] = {}
            for k, a in sorted(self._keys.items()):
                row: dict[str, Any] = {"accepted": a.accepted, **{kind: a.dropped(kind) for kind in DROP_KINDS}}
                dropped = {p: {kind: b.dropped.get(kind, 0) for kind in DROP_KINDS}
                           for p, b in sorted(a.buckets.items()) if b.dropped}
                if dropped:
                    row["dropped_from"] = dropped
                out[k] = row
            return out
