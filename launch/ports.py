"""Which ports one ``radseek run`` stack uses: fixed PX4-SITL-style instance offsets, or the first free instance.

PX4 SITL's convention (``px4 -i N``, ``Tools/sitl_multiple_run.sh``; docs.px4.io "Multi-Vehicle Simulation"):
instance ``i`` sends its API/offboard MAVLink to UDP ``14540 + i`` (MAVSDK ``udpin://0.0.0.0:14540+i``) from
local ``14580 + i``, its GCS MAVLink from local ``18570 + i`` to ``14550``, with system id ``1 + i``. radseek
follows it, with vehicle ``v`` of a team at instance ``N`` being PX4 instance ``i = N + v``, and two
additions a stack of separate processes needs:

- the zenoh router of instance ``N`` listens on ``tcp/127.0.0.1:7447 + N`` (zenoh's default port + N);
- the GCS port is ``14550 + i`` while the run records ``flight.mcap``: the recorder *is* that GCS and binds
  the port, so two recording stacks cannot share it (PX4 shares 14550 because only QGroundControl listens
  there). With ``--no-mcap`` nothing in the stack binds it and every vehicle sends to 14550, as in PX4.

``--instance N`` fixes those ports; a port given by its own flag (``--zenoh-port``...) fixes that one. A fixed
port that is in use is refused before anything starts, naming the flag that moves it. With neither, ``radseek
run`` takes the first instance 0..9 whose ports are all free (PX4's API range 14540-14549), else ports the
OS picks. An instance is also claimed with a lock file (``$TMPDIR/radseek-<uid>/instance-N.lock``, held
while the run lives): two runs started at the same moment by one user do not both find instance 0 free
before either has bound it.
"""

from __future__ import annotations

import fcntl
import os
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

ZENOH_BASE, API_BASE, GCS_BASE, API_LOCAL_BASE, GCS_LOCAL_BASE = 7447, 14540, 14550, 14580, 18570
#: instances tried when no port is fixed: PX4 gives MAVSDK/MAVROS 14540..14549
AUTO_INSTANCES = 10


class PortError(Exception):
    """A fixed port (or instance) that cannot be used; the message names the flag that moves it."""


@dataclass
class Ports:
    """The ports of one stack. ``api``, ``gcs``, ``api_local``, ``gcs_local`` and ``sysid`` are vehicle 0's;
    vehicle ``v`` of a team adds ``v`` to each (``gcs`` only while recording: see the module)."""

    instance: int | None  # None: some ports picked by the OS
    zenoh: int
    api: int
    gcs: int
    api_local: int
    gcs_local: int
    sysid: int
    gcs_shared: bool = False  # --no-mcap: every vehicle sends its GCS traffic to the one port (PX4)
    moved_from: str = ""  # why the defaults were not used ("7447 in use"), for the line printed
    _locks: list[int] = field(default_factory=list, repr=False)

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.zenoh}"

    def vehicle(self, v: int) -> dict[str, int]:
        return {"api": self.api + v, "gcs": self.gcs if self.gcs_shared else self.gcs + v,
                "api_local": self.api_local + v, "gcs_local": self.gcs_local + v, "sysid": self.sysid + v}

    def line(self, n_vehicles: int = 1) -> str:
        """One line saying which ports the run uses (and why, if not the defaults)."""
        def span(p: int, n: int) -> str:
            return str(p) if n == 1 else f"{p}-{p + n - 1}"

        where = "" if self.instance is None else f"instance {self.instance}: "
        gcs = span(self.gcs, 1 if self.gcs_shared else n_vehicles)
        text = (f"radseek run: ports: {where}zenoh tcp/127.0.0.1:{self.zenoh}, "
                f"MAVLink API udp {span(self.api, n_vehicles)} (MAVSDK udpin://0.0.0.0:{self.api}), "
                f"GCS udp {gcs}, vehicle local udp "
                f"{span(self.api_local, n_vehicles)},{span(self.gcs_local, n_vehicles)}, "
                f"system id {span(self.sysid, n_vehicles)}")
        return text + (f" ({self.moved_from})" if self.moved_from else "")

    def release(self) -> None:
        for fd in self._locks:
            os.close(fd)
        self._locks.clear()


def tcp_free(port: int, host: str = "127.0.0.1") -> bool:
    """True if ``host:port`` can be listened on now (as the zenoh router will)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as zenoh does: TIME_WAIT is not "in use"
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def udp_free(port: int, host: str = "127.0.0.1") -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _os_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _derived(n: int, record: bool) -> dict[str, int]:
    return {"zenoh": ZENOH_BASE + n, "api": API_BASE + n, "gcs": GCS_BASE + n if record else GCS_BASE,
            "api_local": API_LOCAL_BASE + n, "gcs_local": GCS_LOCAL_BASE + n, "sysid": 1 + n}


#: the flag that fixes each port, named in refusals
FLAGS = {"zenoh": "--zenoh-port", "api": "--mavlink-port", "gcs": "--gcs-port",
         "api_local": "--vehicle-local-ports", "gcs_local": "--vehicle-local-ports"}


def busy(ports: dict[str, int], n_vehicles: int, record: bool) -> list[tuple[str, int]]:
    """The ports this stack would bind that are in use now: (name, port)."""
    taken = []
    if not tcp_free(ports["zenoh"]):
        taken.append(("zenoh", ports["zenoh"]))
    for v in range(n_vehicles):
        if not udp_free(ports["api"] + v, "0.0.0.0"):  # the mission listens on udpin://0.0.0.0:PORT
            taken.append(("api", ports["api"] + v))
        for name in ("api_local", "gcs_local"):
            if not udp_free(ports[name] + v):
                taken.append((name, ports[name] + v))
    if record and not udp_free(ports["gcs"]):  # the recorder listens as vehicle 0's GCS
        taken.append(("gcs", ports["gcs"]))
    return taken


def _lock(n: int) -> int | None:
    """Claim instance ``n`` for this process (None if another radseek run of this user holds it)."""
    folder = Path(tempfile.gettempdir()) / f"radseek-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    fd = os.open(folder / f"instance-{n}.lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def _lock_all(instances: range) -> list[int] | None:
    fds = []
    for n in instances:
        fd = _lock(n)
        if fd is None:
            for f in fds:
                os.close(f)
            return None
        fds.append(fd)
    return fds


def _describe(taken: list[tuple[str, int]]) -> str:
    return ", ".join(f"{port} ({name.replace('_', ' ')})" for name, port in taken)


def choose(*, instance: int | None, fixed: dict[str, int], n_vehicles: int = 1, record: bool = True) -> Ports:
    """The stack's ports. ``fixed``: ports given by their own flag (name -> port, names as in ``FLAGS``);
    ``instance``: ``--instance N`` or None. Raises :class:`PortError` when a fixed port is in use."""
    hint = ("radseek run picks free ports when none is given, or give a free set with --instance N "
            "(zenoh 7447+N, MAVLink 14540+N, like PX4's -i)")
    if instance is not None:
        if instance < 0:
            raise PortError(f"--instance {instance} must be >= 0")
        ports = {**_derived(instance, record), **fixed}
        locks = _lock_all(range(instance, instance + n_vehicles))
        if locks is None:
            raise PortError(f"instance {instance} is used by another radseek run: {hint}")
        taken = busy(ports, n_vehicles, record)
        if taken:
            for fd in locks:
                os.close(fd)
            raise PortError(f"--instance {instance}: in use: {_describe(taken)} (another stack, SITL or GCS?): "
                            "pick another --instance N")
        return Ports(instance, **ports, gcs_shared=not record, _locks=locks)
    if set(fixed) >= set(FLAGS):  # every port given (tests, scripts): no instance to claim
        ports = {**fixed, "sysid": 1}
        taken = busy(ports, n_vehicles, record)
        if taken:
            raise PortError(f"port in use: {_describe(taken)} (another stack, SITL or GCS?): move it with "
                            f"{FLAGS[taken[0][0]]}, or leave the port flags out: {hint}")
        return Ports(None, **ports, gcs_shared=not record)
    # fixed ports must be free whatever the others are (checked on their own, before any instance)
    fixed_taken = [(name, port) for name, port in busy({**_derived(0, record), **fixed}, n_vehicles, record)
                   if name in fixed]
    if fixed_taken:
        name = fixed_taken[0][0]
        raise PortError(f"port in use: {_describe(fixed_taken)} (another stack, SITL or GCS?): move it with "
                        f"{FLAGS[name]}, or leave the port flags out: {hint}")
    first_taken = ""
    for n in range(AUTO_INSTANCES):
        locks = _lock_all(range(n, n + n_vehicles))
        if locks is None:
            first_taken = first_taken or f"instance {n} used by another radseek run"
            continue
        ports = {**_derived(n, record), **fixed}
        taken = busy(ports, n_vehicles, record)
        if not taken:
            return Ports(n if not fixed else None, **ports, gcs_shared=not record,
                         moved_from=f"{first_taken}; picked the first free instance" if first_taken else "",
                         _locks=locks)
        for fd in locks:
            os.close(fd)
        first_taken = first_taken or f"{_describe(taken)} in use"
    # every instance taken: ports the OS picks (a block of n for per-vehicle ports is not guaranteed: check it)
    for _ in range(20):
        ports = {"zenoh": _os_port(socket.SOCK_STREAM), "api": _os_port(socket.SOCK_DGRAM),
                 "gcs": _os_port(socket.SOCK_DGRAM) if record else GCS_BASE, "api_local": _os_port(socket.SOCK_DGRAM),
                 "gcs_local": _os_port(socket.SOCK_DGRAM), "sysid": 1, **fixed}
        if not busy(ports, n_vehicles, record):
            return Ports(None, **ports, gcs_shared=not record,
                         moved_from=f"{first_taken}; instances 0-{AUTO_INSTANCES - 1} all taken: ports from the OS")
    raise PortError(f"no free ports found ({first_taken})")
