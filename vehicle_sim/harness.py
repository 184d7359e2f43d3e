"""Test and benchmark harness: run a vehicle (thread or process) on free loopback ports and talk to it
with a minimal pymavlink ground station. Real sockets, real MAVLink 2; nothing mocked.

The default timeouts only bound waiting for something that should happen, and are generous (30 s and
more) so that a loaded host slows a test down instead of failing it; a test that asserts something does
NOT arrive passes its own short timeout."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import common as M  # noqa: E402

from vehicle_sim.vehicle import Vehicle, VehicleConfig  # noqa: E402

#: every port free_udp_port handed out in this process: the kernel may give a port it just released again, and a
#: caller drawing several ports for one stack (API, GCS, the vehicle's two local ports) must get distinct ones
_HANDED_UDP: set[int] = set()


def free_udp_port() -> int:
    """A loopback UDP port free now and not handed out before by this process."""
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port not in _HANDED_UDP:
            _HANDED_UDP.add(port)
            return port


def thread_config(api_port: int, gcs_port: int, **kw) -> VehicleConfig:
    return VehicleConfig(api_port=api_port, gcs_port=gcs_port, api_local_port=0, gcs_local_port=0, zenoh=False, **kw)


class VehicleThread:
    """A Vehicle running its loop in a background thread of this process."""

    def __init__(self, cfg: VehicleConfig):
        self.vehicle = Vehicle(cfg)
        self._thread = threading.Thread(target=self.vehicle.run, daemon=True, name="vehicle")

    def __enter__(self) -> Vehicle:
        self._thread.start()
        return self.vehicle

    def __exit__(self, *exc) -> None:
        self.vehicle.stop()
        self._thread.join(10)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()


class VehicleProcess:
    """``radseek vehicle`` as a subprocess; ``args`` are extra CLI options."""

    def __init__(self, api_port: int, gcs_port: int, args: list[str] = (), zenoh: bool = False):
        cmd = [sys.executable, "-m", "radseek_cli", "vehicle", "--api-port", str(api_port), "--gcs-port",
               str(gcs_port), "--api-local-port", "0", "--gcs-local-port", "0", *args]
        if not zenoh:
            cmd.append("--no-zenoh")
        self.cmd = cmd
        self.proc: subprocess.Popen | None = None
        self.banner = ""

    def __enter__(self) -> VehicleProcess:
        self.proc = subprocess.Popen(self.cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.banner = self.proc.stdout.readline()
        if "vehicle ready" not in self.banner:
            self.proc.kill()
            raise RuntimeError(f"vehicle did not start: {self.banner}{self.proc.stdout.read()}")
        self._lines: list[str] = []
        # drain its output all along: a full pipe would block the vehicle's logging, and so the vehicle
        self._reader = threading.Thread(target=lambda: self._lines.extend(iter(self.proc.stdout.readline, "")),
                                        daemon=True)
        self._reader.start()
        return self

    def __exit__(self, *exc) -> None:
        assert self.proc is not None
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(5)
        self.output = "".join(self._lines)


class Gcs:
    """A bare pymavlink ground station listening on ``port`` (like QGroundControl on 14550)."""

    def __init__(self, port: int, sysid: int = 255, compid: int = 190, signing_key: bytes | None = None,
                 keepalive: bool = False):
        self.keepalive = keepalive  # send a 2 Hz HEARTBEAT while polling, like a real GCS
        self._last_hb = 0.0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.mav = M.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.mav.robust_parsing = True
        if signing_key is not None:
            self.mav.signing.secret_key = signing_key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.link_id = 3
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
        self.vehicle_addr: tuple[str, int] | None = None
        self.received: list = []

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> Gcs:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def poll(self, timeout: float = 0.05) -> list:
        if self.keepalive and self.vehicle_addr is not None and time.monotonic() - self._last_hb > 0.5:
            self._last_hb = time.monotonic()
            self.heartbeat()
        self.sock.settimeout(timeout)
        out = []
        try:
            data, addr = self.sock.recvfrom(65535)
        except (TimeoutError, BlockingIOError):
            return out
        self.vehicle_addr = addr
        for m in self.mav.parse_buffer(data) or []:
            if m.get_type() != "BAD_DATA":
                out.append(m)
        self.received.extend(out)
        return out

    def wait_vehicle(self, timeout: float = 60.0) -> None:
        """Wait until the vehicle's first datagram arrives (even one we cannot verify)."""
        deadline = time.monotonic() + timeout
        while self.vehicle_addr is None:
            if time.monotonic() > deadline:
                raise TimeoutError("no datagram from the vehicle")
            self.poll(0.05)

    def recv(self, kind: str | set[str], cond: Callable | None = None, timeout: float = 30.0):
        kinds = {kind} if isinstance(kind, str) else kind
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for m in self.poll(0.05):
                if m.get_type() in kinds and (cond is None or cond(m)):
                    return m
        raise TimeoutError(f"no {kinds} in {timeout} s")

    def send(self, msg) -> None:
        assert self.vehicle_addr is not None, "wait_vehicle() first"
        self.sock.sendto(msg.pack(self.mav), self.vehicle_addr)
        self.mav.seq = (self.mav.seq + 1) % 256

    def send_raw(self, data: bytes) -> None:
        assert self.vehicle_addr is not None
        self.sock.sendto(data, self.vehicle_addr)

    def heartbeat(self) -> None:
        self.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def command(self, command: int, *params: float, timeout: float = 30.0) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(M.MAVLink_command_long_message(1, 1, command, 0, *p))
        return self.recv("COMMAND_ACK", lambda m: m.command == command, timeout).result

    def upload(self, items: list, timeout: float = 60.0) -> int:
        """Upload MISSION_ITEM_INT messages (seq order) answering the vehicle's requests; returns the ACK type."""
        self.send(M.MAVLink_mission_count_message(1, 1, len(items), 0))
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = self.recv({"MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"}, timeout=timeout)
            if m.get_type() == "MISSION_ACK":
                return m.type
            self.send(items[m.seq])
        raise TimeoutError("upload")


def item(seq: int, command: int, lat: float = 0.0, lon: float = 0.0, alt: float = 0.0, p1: float = 0.0,
         frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, p4: float = float("nan")):
    return M.MAVLink_mission_item_int_message(1, 1, seq, frame, command, 0, 1, p1, 0.0, 0.0, p4,
                                              int(round(lat * 1e7)), int(round(lon * 1e7)), alt, 0)
