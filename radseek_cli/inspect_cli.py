"""``radseek topics``: list the live radseek zenoh keys with their message rates.

Listens to ``radseek/**`` (or ``--key``) for ``--duration`` wall seconds and prints one row per key:
messages seen, rate in messages per wall second (from the first to the last arrival), the rate in
simulation time when that vehicle's ``sim/clock`` was seen (wall rate / speed-up), mean payload size
and the payload schema. ``--markdown`` prints instead the topic table of ``docs/topics.md``, generated
from ``radseek/topics.py`` (no zenoh needed).
"""

from __future__ import annotations

import argparse
import inspect
import json
import re
import sys
import threading
import time
from dataclasses import MISSING, dataclass, fields

from mission import key_accounts
from radseek import topics, zenoh_auth
from radseek.zenoh_session import add_arguments
from radseek_cli.serve import open_session_or_report, serve_until_stopped

# who publishes each topic (documentation only; the schema itself lives in radseek/topics.py)
PUBLISHERS: dict[str, str] = {
    topics.SIM_CLOCK: "vehicle, or `radseek detector --clock own`",
    topics.SIM_TRUTH_POSE: "vehicle (read only by the detector emulator)",
    topics.POSE: "vehicle",
    topics.HISTOGRAM: "detector",
    topics.RAW_FRAME: "detector",
    topics.DETECTOR_STATUS: "detector",
    topics.MISSION_STATE: "mission",
    topics.MISSION_LOCKSTEP: "mission (read by the vehicle with `--lockstep`)",
    topics.ESTIMATE: "mission (a team's joint estimate under the vehicle name `team`)",
    topics.TEAM_STATUS: "mission, in a team (`radseek run --vehicles N`)",
    topics.PLAN: "mission",
}
RATES: dict[str, str] = {
    topics.SIM_CLOCK: "10 Hz or faster",
    topics.HISTOGRAM: "10 Hz",
    topics.RAW_FRAME: "10 Hz",
    topics.DETECTOR_STATUS: "1 Hz",
    topics.MISSION_LOCKSTEP: "every frame, and 2 Hz wall while busy",
}


@dataclass
class KeyStats:
    """The messages seen on one key: how many, their bytes, when the first and the last arrived."""
    count: int = 0
    nbytes: int = 0
    seen: tuple[float, float] | None = None  # wall times of the first and the last message (None: none yet)

    def add(self, n: int, wall: float) -> None:
        self.count += 1
        self.nbytes += n
        self.seen = (wall if self.seen is None else self.seen[0], wall)

    @property
    def rate(self) -> float:
        """Messages per wall second from inter-arrival times (0 with fewer than two messages)."""
        if self.seen is None or self.count < 2:
            return 0.0
        span = self.seen[1] - self.seen[0]
        return (self.count - 1) / span if span > 0 else 0.0


def schema_name(full_key: str) -> str:
    try:
        topic = topics.topic_of(full_key)
    except ValueError:
        return "?"
    if topic == topics.RAW_FRAME:
        return "board frame (binary)"
    cls = topics.PAYLOADS.get(topic)
    return cls.__name__ if cls else "?"


def table(stats: dict[str, KeyStats], speedups: dict[str, float]) -> str:
    """The rows printed by ``radseek topics`` (speedups: vehicle -> sim/clock speed-up)."""
    rows = [("KEY", "MSGS", "HZ", "SIM HZ", "AVG B", "SCHEMA")]
    for k in sorted(stats):
        s = stats[k]
        vehicle = k.split("/")[1] if k.count("/") >= 2 else ""
        sim = f"{s.rate / speedups[vehicle]:.1f}" if vehicle in speedups and s.rate > 0 else "-"
        rows.append((k, str(s.count), f"{s.rate:.1f}", sim, str(s.nbytes // max(s.count, 1)), schema_name(k)))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join(
        "  ".join(c.ljust(w) if i in (0, 5) else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths, strict=True)))
        .rstrip()
        for r in rows
    )


_FIELD_RE = re.compile(r"^\s+(\w+):\s*([^=#]+?)\s*(?:=\s*([^#]+?))?\s*(?:#\s*(.*))?$")


def _field_comments(cls: type) -> dict[str, tuple[str, str]]:
    """field name -> (default text, comment) read from the class source in topics.py: the field's trailing comment,
    else the comment lines right above it."""
    out = {}
    above: list[str] = []
    for line in inspect.getsource(cls).splitlines():
        m = _FIELD_RE.match(line)
        if m and m.group(1) != "TOPIC":
            out[m.group(1)] = ((m.group(3) or "").strip(), (m.group(4) or " ".join(above)).strip())
        above = [*above, line.strip()[1:].strip()] if line.strip().startswith("#") else []
    return out


def _default(f) -> str:
    """A field's default as the topic table shows it (the declaration's metadata left out)."""
    if f.default is not MISSING:
        return f"`{json.dumps(f.default) if isinstance(f.default, str) else repr(f.default)}`"
    if f.default_factory is not MISSING:
        return f"`field(default_factory={f.default_factory.__name__})`"
    return "required"


#: one ``-k`` per JSON topic, every vehicle's: zenoh-cli's json decoder prints a traceback for each binary raw frame
#: that ``radseek/**`` would bring (one per 100 ms), and a key expression cannot leave ``detector/raw`` out
ZENOH_CLI_JSON_KEYS = " ".join(f"-k '{topics.all_keys().removesuffix('**')}{t}'" for t in topics.PAYLOADS)
ZENOH_CLI_COMMAND = ("zenoh --mode peer --connect tcp/127.0.0.1:7447 --cfg 'scouting/multicast/enabled:false' "
                     f"--cfg 'listen/endpoints:[]' subscribe {ZENOH_CLI_JSON_KEYS} --decoder json "
                     "--line '{key} {value}'")
ZENOH_CLI_RUN_COMMAND = (f"zenoh --config OUT/zenoh/observer.json5 subscribe {ZENOH_CLI_JSON_KEYS} --decoder json "
                         "--line '{key} {value}'")
ZENOH_CLI_RECIPE = f"""The third-party `zenoh` command (PyPI `zenoh-cli`, installed with radseek's dev extras) shows the
same keys. It needs the router's endpoint (without `--connect` it finds nothing: multicast scouting is off
on radseek's loopback network), `--decoder json` (without it payloads print as base64) and one `-k` per JSON
topic: `-k 'radseek/**'` would also bring the binary `detector/raw`, and zenoh-cli's json decoder prints a
traceback for each of its frames (10 a second):

```sh
{ZENOH_CLI_COMMAND}
```

prints one line per message, e.g. `radseek/uav0/sim/clock {{"t": 12.3, "speedup": 1.0}}`. Keep one key
(`-k 'radseek/uav0/detector/histogram'`) to follow one topic; for the raw frames use `radseek echo detector/raw`
(decoded) or `--decoder base64`. `tests/test_cli_promises.py` runs this command beside a detector's raw frames.

The router of `radseek run` admits only the run's users (see "Authentication" below): watch it with the
observer's client configuration the run writes, which holds the endpoint and the credentials
(`tests/test_zenoh_auth.py` runs this command):

```sh
{ZENOH_CLI_RUN_COMMAND}
```

`radseek echo KEY --zenoh-config OUT/zenoh/observer.json5` and `radseek topics --zenoh-config ...` take the same
file."""


AUTH_SECTION = f"""## Authentication

`radseek run` starts its router with a per-run secret: `OUT/zenoh/credentials` (mode 0600, in a 0700 folder;
never printed) lists one random password per user, in zenoh's own `usrpwd` dictionary format
(`USER:PASSWORD` per line). The run names it to every process it starts by the environment variable
`{zenoh_auth.CREDENTIALS_ENV}`: the router (`radseek router`) then admits only those users
(`transport.auth.usrpwd.dictionary_file`) and applies an `access_control` built from their names (default
deny); every other process connects as its own user from the same file. Every user may subscribe to every
key; a user may put only the keys its name gives it, so a put on another's key is dropped by the router and
reaches no subscriber, and a process without the secret cannot open a session at all
(`radseek/zenoh_auth.py`, `tests/test_zenoh_auth.py`):

| user name | may put |
| --- | --- |"""

AUTH_HARDWARE = f"""`ROLE.LABEL@VEHICLE` (e.g. `detector.board7@uav0`) is a second identity with the same rights: a
process looks for its own name (`detector@uav0`) and otherwise takes the first line of its role and vehicle
(a reader: the first reader's line). A process given `--zenoh-config FILE` uses that file's credentials.

A process the router refuses (a wrong password, a user the router does not list) stops at once, with one line
naming its user and the router's endpoint, e.g. `radseek vehicle: the zenoh router at tcp/127.0.0.1:7447
refused user 'vehicle@uav0' (wrong password, or that router has other credentials): stopped`; a vehicle does
not fly on unheard. `radseek run` then ends with exit code 1 quoting that line (`radseek run: vehicle exited
with 1: ...`) and keeps what was recorded (`tests/test_zenoh_refused.py`).

**A hardware board or a ground station with its own credential.** Write a credentials file for the router
with a line per user, one `USER:PASSWORD` each (no blank lines or comments: zenoh reads the file as it is),
e.g. `detector.board7@uav0:<secret>` for the board's companion computer and `groundstation:<secret>` for a
ground station, start the router with it and give each machine a file holding its own line:

```sh
{zenoh_auth.CREDENTIALS_ENV}=router-users radseek router --listen tcp/0.0.0.0:7447
{zenoh_auth.CREDENTIALS_ENV}=board7 radseek detector --connect tcp/ROUTER:7447 ...   # the board's publisher
{zenoh_auth.CREDENTIALS_ENV}=gcs radseek echo detector/histogram --connect tcp/ROUTER:7447   # ground station
```

A file with an unknown role, a repeated user or a malformed line is refused by line number; an empty one too
(zenoh would take it as "no authentication"). Without `{zenoh_auth.CREDENTIALS_ENV}` the router is open, as
before, to any session that reaches it (a hand-started stack on loopback). The ACL cannot be changed while
the router runs: restart it to add a user. `usrpwd` authenticates a session; it does not encrypt its traffic:
beyond loopback, listen and connect on zenoh's `tls/` endpoints as well. A detector on its own clock
(`--clock own`) publishes `sim/clock`, which a `detector` user may not put: run it alone on an open router."""


#: what the authentication and the mission's key accounting protect against, and their limits (issue 34)
THREAT_MODEL = f"""\
**What this protects against, and what it does not.** The unit of trust is a line of the credentials file. A
process that holds none cannot open a session; one that holds a line can put only the keys that line's role
gives it (`tests/test_zenoh_auth.py`; a team run whose router refuses an outsider and drops every put of a
process flooding and forging the stack's keys with the observer's credential flies the unattacked flight,
`tests/test_team_flood.py`). A process holding a role's own credential
*is* that role: the router cannot tell a second process on the board that uses `detector@uav0` from the board,
and the missions of one team share `radseek/team/**`. Against such a publisher the mission only accounts
(`mission/key_accounts.py`): samples over {key_accounts.FLOOD_FACTOR:g}x a key's contract rate are dropped per
publisher as a flood, a second publisher on a key is dropped as forged while the first speaks, a copy of the
first's zenoh id with a sequence number already taken is dropped as a forged sequence, and each is named per key
and publisher in `mission_summary.json` and on `radseek run`'s stderr (`tests/test_run_flood_summary.py`: a run
attacked so with the detector's credential flies the unattacked flight frame for frame). Payloads outside their
schema (a clock at -5 s or 1e9 s, junk bytes) are dropped and counted by every subscriber. Left as limits,
because zenoh lets a publisher stamp any `source_info` and does not tell a subscriber which user put a sample:

- *First speaker owns a key*: a holder of the role's credential that puts a key before the real process is taken
  as its publisher, and the real one's samples are dropped as a second publisher's (named) for as long as it
  runs: refused while the first spoke, it never takes the key over, even after the first has been silent
  {key_accounts.OWNER_SILENT_WALL_S:g} wall seconds (the rule that keeps a flooder from waiting out the owner's
  pauses); only a restarted process, a new publisher, does.
- *The copy race*: a copy of a real histogram with the real id and sequence number and forged counts that reaches
  the mission before the original (a router delivers to its subscribers one after another) is taken, and the
  original is dropped as the forged sequence: named, not prevented.
- *One drop accounting*: only the mission rates samples per publisher. The clock's followers (detector, recorder:
  `sim/clock`), the detector (`sim/truth_pose`) and the vehicle (`mission/lockstep`) drop, count and log invalid
  payloads only (`radseek/payload_drops.py`), in their own logs: each of those keys has one putting role under the
  ACL, so a flood there is that role's own, and `radseek run` could sum their counts only from processes that
  end well (a killed one hands nothing back).

What would close the first two: per-sample signatures by a key the transport credential does not carry (the
board signing each frame's sequence number, time and counts in its firmware; the mission checking them), so that
a stolen session credential no longer forges a frame. Not built: under this model a stolen role credential is a
stolen role. A router started without `{zenoh_auth.CREDENTIALS_ENV}` (a stack started by hand) trusts every
process that reaches it, and only the key accounting stands."""


#: the router's congestion policy (``radseek.zenoh_qos``), as docs/topics.md says it
CONGESTION_SECTION = """\
**Congestion: a flood drops samples, it closes no connection.** Every router `radseek router` builds (under
`radseek run`, by hand, in `docker/compose.yaml`; not one given `--zenoh-config FILE`) rewrites, on ingress,
every put and delete on `radseek/**` to congestion control DROP at priority `data`, and those on
`radseek/*/pose` and `radseek/*/sim/**` to DROP at `data_high`, whatever the publisher asked (zenoh's
`qos.network` overwrite, declared once in `radseek/zenoh_qos.py`). Without it, a user that puts its own key
with congestion control BLOCK toward a subscriber that cannot keep up fills the router's queue toward that
subscriber, and after zenoh's 5 s `block.wait_before_close` the router closes the *subscriber's* connection
("Unable to push non droppable network message ... Closing transport!", now in the router's log), losing all
it would have received meanwhile. Measured (`tests/test_zenoh_qos.py`: `detector@uav0` floods
`detector/histogram` with BLOCK for 7 s while the observer spends 50 ms per flood sample and `vehicle@uav0`
puts `pose` at 20 Hz): without the overwrite the observer's connection was closed and 139 of the 140 poses
sent during the flood (and 1 of the 30 after) never reached it; with it no connection was closed, the flood
was thinned by the router (about 4,300 of 3.2 million puts delivered) and 200 of 200 poses arrived, at
`data_high`, in their own transmit queue. Dropping is the price: a subscriber too slow for what it is sent
loses samples of the flooded priority (a gap in a histogram's `seq` shows where); the vehicle's
keys, which only `vehicle` users may put, keep their own queue ahead of detector and mission keys."""


def topics_markdown() -> str:
    """The topic table of docs/topics.md, generated from ``radseek/topics.py``."""
    lines = [
        "# radseek zenoh topics",
        "",
        "Generated from `radseek/topics.py` by `radseek topics --markdown > docs/topics.md`; do not edit by hand",
        "(`tests/test_inspection.py` fails when this file is out of date).",
        "",
        f"Keys are `{topics.PREFIX}/<vehicle>/<topic>` (default vehicle `{topics.DEFAULT_VEHICLE}`). Payloads are",
        "UTF-8 JSON objects except `detector/raw`, the board's binary frame (docs/frame-format.md). Frames:",
        "local ENU metres, yaw in radians counter-clockwise from +x (east); times in simulation seconds from",
        "the shared clock. Topics under `sim/` carry the simulated truth: only the detector emulator reads them.",
        "",
        "Each payload's JSON schema is generated from its declaration (`radseek.topics.json_schema`; the MCAP log",
        "and `radseek view` hand it to Foxglove). So that Foxglove Studio 1.x's JSON-schema reader takes every one",
        "(docs/vehicle.md), a field whose default is `None` is left out while it is None, never sent as null; points",
        "and covariance blocks go in one flat list of numbers (no arrays of arrays); an object's keys are declared.",
        "",
        "Every sample carries its zenoh encoding with a schema name (the table's last column), so a subscriber",
        "that does not know radseek can tell JSON from binary by `sample.encoding` (`tests/test_topic_encodings.py`).",
        "",
        "| key | publisher | rate | payload | zenoh encoding |",
        "| --- | --- | --- | --- | --- |",
    ]
    all_topics = list(topics.PAYLOADS)
    if topics.RAW_FRAME not in all_topics:
        all_topics.insert(all_topics.index(topics.HISTOGRAM) + 1, topics.RAW_FRAME)
    for t in all_topics:
        cls = topics.PAYLOADS.get(t)
        payload = f"`{cls.__name__}` (JSON)" if cls else "board frame (90 bytes binary)"
        lines.append(f"| `{topics.PREFIX}/<vehicle>/{t}` | {PUBLISHERS.get(t, '?')} | {RATES.get(t, 'on change')} "
                     f"| {payload} | `{topics.encoding(t)}` |")
    lines += ["", "## Watching with zenoh-cli", "", ZENOH_CLI_RECIPE, "", AUTH_SECTION]
    for role, keys in zenoh_auth.PUTS.items():
        shared = ", ".join(f"`{k}`" for k in zenoh_auth.SHARED_PUTS.get(role, ()))
        lines.append(f"| `{role}@VEHICLE` | " + ", ".join(f"`{topics.PREFIX}/VEHICLE/{k}`" for k in keys)
                     + (f", {shared}" if shared else "") + " |")
    lines.append("| any other name (`recorder`, `observer`, `groundstation`) | nothing: it only subscribes |")
    lines += ["", AUTH_HARDWARE, "", THREAT_MODEL, "", CONGESTION_SECTION]
    flag_bits = [(n, getattr(topics, n)) for n in dir(topics) if n.startswith("FLAG_")]
    lines += ["", "## Histogram flag bits", "", "| bit | name | meaning |", "| --- | --- | --- |"]
    src = inspect.getsource(topics)
    for name, bit in sorted(flag_bits, key=lambda nb: nb[1]):
        m = re.search(rf"^{name}\s*=.*#\s*(.*)$", src, re.M)
        lines.append(f"| 0x{bit:02x} | `{name}` | {m.group(1).strip() if m else ''} |")
    for t, cls in topics.PAYLOADS.items():
        doc = inspect.cleandoc(cls.__doc__ or "").replace("\n", " ")
        lines += ["", f"## `{t}`: {cls.__name__}", "", doc, "", "| field | type | default | notes (units) |",
                  "| --- | --- | --- | --- |"]
        comments = _field_comments(cls)
        for f in fields(cls):
            note = comments.get(f.name, ("", ""))[1]
            if topics.KEYS in f.metadata:
                keys = ", ".join(f"`{k}` ({kind})" for k, kind in f.metadata[topics.KEYS].items())
                note = f"{note}{'; ' if note else ''}keys: {keys}"
            lines.append(f"| `{f.name}` | `{f.type}` | {_default(f)} | {note} |")
    lines += ["", f"## `{topics.RAW_FRAME}`", "",
              "One board frame per message, bytes as on the wire: see docs/frame-format.md. Decode it with",
              "`radseek.board_wire.decode_frame` (raises `FrameError` on a truncated or corrupted frame).", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="radseek topics", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--duration", type=float, default=3.0, help="wall seconds to listen (default 3)")
    p.add_argument("--key", default=topics.all_keys(), help="key expression to list (default radseek/*/**)")
    p.add_argument("--markdown", action="store_true", help="print the topic table (docs/topics.md) and exit")
    add_arguments(p)
    args = p.parse_args(argv)
    if args.markdown:
        print(topics_markdown())
        return 0
    if args.duration <= 0:
        p.error("--duration must be > 0")
    session = open_session_or_report("radseek topics", args)
    if session is None:
        return 1
    lock = threading.Lock()
    stats: dict[str, KeyStats] = {}
    speedups: dict[str, float] = {}

    def on_sample(sample) -> None:
        k, payload = str(sample.key_expr), sample.payload.to_bytes()
        now = time.monotonic()
        with lock:
            stats.setdefault(k, KeyStats()).add(len(payload), now)
        if k.endswith("/" + topics.SIM_CLOCK):
            try:
                speedups[k.split("/")[1]] = topics.SimClock.from_bytes(payload).speedup
            except topics.PayloadError:
                pass

    sub = session.declare_subscriber(args.key, on_sample)
    serve_until_stopped(args.duration, ready=lambda: print(
        f"radseek topics: listening to {args.key} for {args.duration:g} s (Ctrl-C stops it early)", file=sys.stderr,
        flush=True))
    sub.undeclare()
    session.close()
    with lock:
        if not stats:
            print(f"no messages on {args.key} in {args.duration:g} s (is anything publishing to {args.connect}?)")
            return 0
        print(table(stats, speedups))
    return 0
