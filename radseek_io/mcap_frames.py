"""A flight read back from its MCAP log (``radseek run``'s ``flight.mcap``, ``radseek record``): the frame
records the mission's recorder made in the air, rebuilt from the recorded topics.

The rebuild is the recorder's own rule (``mission/recorder.py``, ``mission/mission_process.py``):

- each ``detector/histogram``, in the order it was received, is joined with the estimated ``pose`` by the
  one pose-join rule (``radseek.frame_record.pose_for``: interpolated at the frame's mid-time), fed
  with the poses received up to the one at the frame's end time (the mission records a histogram once that
  pose is in) and ``radseek.frame_record.FrameRecord.from_histogram`` makes the record;
- the dwell index is the ``dwell_index`` of the last ``mission/state`` published for an *earlier* frame
  (``state.t < frame.t``): the mission sets its dwell index while it handles the frame ending at ``t``
  and announces it at once in a state stamped ``t``; the next frame it records ends after ``t``. Exact
  under lockstep (the default of ``radseek run``: no later frame exists while the mission decides); a
  free-running flight (``--no-lockstep``) may disagree with ``frames.csv`` on a frame or two at a dwell's
  edges, since there frames keep arriving while the mission decides;
- payloads that fail their schema are dropped, as the mission drops them (``dropped`` counts them);
- the flight ends at the mission's state of phase ``done`` (``DONE_PHASE``): the mission stops recording
  once it has landed and says so stamped with the last frame it took; the log goes on while the stack
  shuts down (the vehicle runs free, the detector keeps measuring), and those frames are left out. A log
  without that state (the mission was killed) keeps every frame.

Usable records (``FrameRecord.usable``) make the ``Frames`` of a ``radseek.dataset.Dataset``, as
``frames.csv`` holds them but at full precision (``frames.csv`` rounds poses to 0.1 mm). The first
``estimate`` message tells at which dwell the mission first had an estimate (``first_dwell``), which
``radseek replay`` needs to start where the flight did. Only flight-software topics are read, never
``sim/``.

``McapFrameError`` (a ``ValueError``) names the file when it is missing, not MCAP, truncated (no footer:
the recorder was killed before it finished the file) or damaged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from radseek import topics
from radseek.dataset import Dataset, Frames, Scenario
from radseek.frame_record import POSE_KEEP_S, FrameRecord, pose_for
from radseek.pose_history import PoseHistory
from radseek.truth import Truth

#: the first and last bytes of every MCAP file (the specification's magic)
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: topics the rebuild reads (flight software only: never sim/)
READ_TOPICS = (topics.HISTOGRAM, topics.POSE, topics.MISSION_STATE, topics.ESTIMATE)
EPS_T = 1e-6  # s: the mission's tolerance on "the pose at the frame's end has arrived"
#: ``MissionState.phase`` of the mission's last state: landed, recording stopped
DONE_PHASE = "done"


class McapFrameError(ValueError):
    """An MCAP file that cannot be read back as a flight (the message names the file)."""


@dataclass
class RecordedFlight:
    """What ``read_flight`` rebuilt from one MCAP file."""

    path: Path
    records: list[FrameRecord]  # every received frame, in the order received (usable and flagged)
    estimates: list[topics.Estimate]  # the mission's published estimates, in order
    states: list[topics.MissionState]  # the mission's published states, in order
    end_t: float | None = None  # sim time of the last frame the mission recorded (its "done" state), if known
    dropped: dict[str, int] = field(default_factory=dict)  # topic -> payloads that failed their schema

    @cached_property
    def frames(self) -> Frames:
        """The usable records as ``frames.csv`` columns (rows in the order recorded; built once)."""
        return Frames.from_records([r for r in self.records if r.usable])

    def first_dwell(self) -> int | None:
        """The dwell count at which the mission published its first estimate (None: it never did): the
        number of dwells among the usable frames up to that estimate's time (as ``radseek replay`` counts)."""
        if not self.estimates:
            return None
        f = self.frames
        upto = f.dwell[(f.t <= self.estimates[0].t + EPS_T) & (f.dwell >= 0)]
        return int(len(np.unique(upto))) or None

    def dataset(self, scenario: Scenario, truth: Truth | None = None) -> Dataset:
        return Dataset(frames=self.frames, scenario=scenario, truth=truth, path=self.path)


def _check_file(path: Path) -> None:
    """McapFrameError unless ``path`` is a complete MCAP file (magic at both ends)."""
    if not path.exists():
        raise McapFrameError(f"{path}: no such file")
    if not path.is_file():
        raise McapFrameError(f"{path}: not a file (expected an MCAP log such as a run's flight.mcap)")
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(len(MCAP_MAGIC))
        f.seek(max(size - len(MCAP_MAGIC), 0))
        tail = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise McapFrameError(f"{path}: not an MCAP file (it does not start with the MCAP magic)")
    if size < 2 * len(MCAP_MAGIC) or tail != MCAP_MAGIC:
        raise McapFrameError(f"{path}: truncated MCAP file (no footer: the recorder did not finish it, e.g. it "
                             "was killed); the run's dataset/ is the primary record of the flight")


def read_messages(path: str | Path, names: tuple[str, ...] = READ_TOPICS,
                  vehicle: str = topics.DEFAULT_VEHICLE) -> dict[str, list[bytes]]:
    """The payloads of topics ``names`` of ``vehicle`` in an MCAP log, per topic name in the order they
    were recorded (the channel's sequence numbers). McapFrameError names the file when it cannot be read."""
    from mcap.reader import make_reader

    path = Path(path)
    _check_file(path)
    keys = {topics.key(name, vehicle): name for name in names}
    found: dict[str, list[tuple[int, int, bytes]]] = {name: [] for name in names}
    try:
        with open(path, "rb") as f:
            for n, (_schema, channel, message) in enumerate(
                    make_reader(f).iter_messages(topics=list(keys), log_time_order=False)):
                found[keys[channel.topic]].append((message.sequence, n, bytes(message.data)))
    except Exception as exc:  # noqa: BLE001 - McapError, struct.error, a zstd error of a corrupt chunk, ...
        raise McapFrameError(f"{path}: damaged MCAP file ({type(exc).__name__}: {exc})") from None
    return {name: [data for *_, data in sorted(msgs, key=lambda m: m[:2])] for name, msgs in found.items()}


def _decoded(payloads: list[bytes], schema: type, dropped: dict[str, int]) -> list:
    out = []
    for data in payloads:
        try:
            out.append(schema.from_bytes(data))
        except topics.PayloadError:
            dropped[schema.TOPIC] = dropped.get(schema.TOPIC, 0) + 1
    return out


def rebuild_records(histograms: list[topics.Histogram], poses: list[topics.Pose],
                    states: list[topics.MissionState],
                    channel_edges_keV: np.ndarray | None = None) -> list[FrameRecord]:
    """The frame records the mission's recorder made from these messages (each list in received order)."""
    history: PoseHistory[topics.Pose] = PoseHistory(keep_s=POSE_KEEP_S)
    latest = -np.inf
    p = s = 0
    dwell = -1
    records = []
    for hist in histograms:
        while p < len(poses) and latest < hist.t - EPS_T:  # poses received before the frame was recorded
            if history.add(poses[p]):
                latest = poses[p].t
            p += 1
        while s < len(states) and states[s].t < hist.t - EPS_T:  # states announced for earlier frames
            dwell = states[s].dwell_index
            s += 1
        records.append(FrameRecord.from_histogram(hist, pose_for(hist, history), dwell,
                                                   channel_edges_keV))
    return records


def read_flight(path: str | Path, scenario: Scenario | None = None,
                vehicle: str = topics.DEFAULT_VEHICLE) -> RecordedFlight:
    """Rebuild a flight's frame records from its MCAP log (``scenario`` gives the channel edges the
    records carry; None leaves them out). McapFrameError names the file when it cannot be read or holds
    no histogram of ``vehicle``."""
    path = Path(path)
    msgs = read_messages(path, vehicle=vehicle)
    dropped: dict[str, int] = {}

    def decode(name: str, schema: type) -> list:
        return _decoded(msgs[name], schema, dropped)

    histograms = decode(topics.HISTOGRAM, topics.Histogram)
    if not histograms:
        raise McapFrameError(f"{path}: no valid {topics.key(topics.HISTOGRAM, vehicle)} message: not a recorded "
                             f"flight of vehicle {vehicle!r}")
    states = decode(topics.MISSION_STATE, topics.MissionState)
    records = rebuild_records(histograms, decode(topics.POSE, topics.Pose), states,
                              None if scenario is None else scenario.channel_edges_keV)
    end_t = next((st.t for st in states if st.phase == DONE_PHASE), None)
    if end_t is not None:
        records = [r for r in records if r.t <= end_t + EPS_T]
    return RecordedFlight(path, records, decode(topics.ESTIMATE, topics.Estimate), states, end_t=end_t,
                          dropped=dropped)


def beside(path: str | Path, name: str) -> Path | None:
    """The run's file ``name`` next to its MCAP log: ``dataset/NAME`` (the recorded dataset of
    ``radseek run``), else ``NAME`` in the same folder; None when neither exists."""
    folder = Path(path).parent
    return next((p for p in (folder / "dataset" / name, folder / name) if p.is_file()), None)
