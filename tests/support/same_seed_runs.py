"""Two `radseek run`s of one seed flown at the same time (default scene, 50x, 4 dwells, seed 0, every port free),
once per test run, the second attacked while it flies (``Attack``). A run costs ~12 s of CPU (six processes), and
three tests flew their own: tests/test_lockstep_repro.py holds that the two are the same flight (so the attack
changed nothing), tests/test_one_world.py that the first is the in-process driver's flight, and
tests/test_run_mcap.py checks the second's flight.mcap, replay and what the attack achieved (nothing)."""

from __future__ import annotations

import subprocess
import sys
import threading

import pytest

from radseek import topics
from radseek.zenoh_auth import read_credentials
from radseek.zenoh_session import RouterRefused, open_session
from tests.conftest import free_port
from tests.support.once_per_run import once_per_run
from vehicle_sim.harness import free_udp_port

RUN_TIMEOUT_S = 900
SEED = 0
MAX_DWELLS = 4
SCENE = "default"
FORGED_T = 9e6  # s: a sim time no flight of these runs reaches (valid by the schema: t <= 1e7)
FORGED_SEQ = topics.SEQ_MAX  # a frame counter the emulator never reaches in a flight


class Attack(threading.Thread):
    """Forges the run's keys while it flies, as a local process holding some of its secrets would."""

    def __init__(self, out, zenoh_port: int):
        super().__init__(daemon=True)
        self.out, self.endpoint = out, f"tcp/127.0.0.1:{zenoh_port}"
        self.stop = threading.Event()
        self.refused: str | None = None  # the unauthenticated session's refusal
        self.puts = 0
        self.clock_at_puts: list[float] = []  # the genuine sim time when forged puts went out

    def run(self) -> None:
        creds = self.out / "zenoh" / "credentials"
        while not creds.exists() and not self.stop.wait(0.05):
            pass
        if self.stop.is_set():
            return
        users = {u.name: u for u in read_credentials(creds)}
        try:
            open_session(connect=self.endpoint, wait_for_router_s=120).close()
        except RouterRefused as exc:
            self.refused = str(exc)
        now = [0.0]
        with open_session(connect=self.endpoint, user=users["detector@uav0"], wait_for_router_s=120) as det, \
                open_session(connect=self.endpoint, user=users["observer"], wait_for_router_s=120) as obs:
            obs.declare_subscriber(topics.key(topics.SIM_CLOCK),
                                   lambda s: now.__setitem__(0, topics.SimClock.from_bytes(s.payload.to_bytes()).t))
            clock = topics.SimClock(t=FORGED_T, speedup=1.0).to_bytes()
            lockstep = topics.MissionLockstep(t=FORGED_T, until=FORGED_T, busy=False).to_bytes()
            hist = topics.Histogram(seq=FORGED_SEQ, board_time=1.0, t=1.0, duration=0.1,
                                    counts=[topics.COUNT_MAX] * topics.N_CHANNELS).to_bytes()
            while not self.stop.wait(0.01):
                det.put(topics.key(topics.SIM_CLOCK), clock)  # the detector's password, the vehicle's key
                det.put(topics.key(topics.MISSION_LOCKSTEP), lockstep)  # ... and the mission's
                obs.put(topics.key(topics.HISTOGRAM), hist)  # a reader's password, the detector's key
                self.puts += 3
                self.clock_at_puts.append(now[0])


def _cmd(out, zenoh_port: int) -> list[str]:
    return [sys.executable, "-m", "radseek_cli", "run", SCENE, "--out", str(out), "--quiet", "--speedup", "50",
            "--max-dwells", str(MAX_DWELLS), "--seed", str(SEED), "--zenoh-port", str(zenoh_port),
            "--mavlink-port", str(free_udp_port()), "--gcs-port", str(free_udp_port()),
            "--vehicle-local-ports", f"{free_udp_port()},{free_udp_port()}", "--timeout", str(RUN_TIMEOUT_S)]


def same_seed_runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The two runs (started together, so they also compete for the CPU differently): ``outs``, ``codes``,
    ``outs_text`` (stdout), ``errs`` (stderr), and ``attack``, what the second run's attacker saw
    (``refused``, ``puts``, ``clock_at_puts``)."""

    def fly(folder) -> dict:
        outs = [folder / "a", folder / "b"]
        ports = [free_port(), free_port()]
        attack = Attack(outs[1], ports[1])
        attack.start()
        procs = [subprocess.Popen(_cmd(o, port), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for o, port in zip(outs, ports, strict=True)]
        results = []
        try:
            for p in procs:
                results.append(p.communicate(timeout=RUN_TIMEOUT_S + 60))
        finally:
            attack.stop.set()
            attack.join(60)
            for p in procs:
                if p.poll() is None:
                    p.kill()
                    p.wait()
        return {"outs": outs, "codes": [p.returncode for p in procs], "outs_text": [out for out, _ in results],
                "errs": [err for _, err in results],
                "attack": {"refused": attack.refused, "puts": attack.puts, "clock_at_puts": attack.clock_at_puts}}

    return once_per_run(tmp_path_factory, "same-seed-runs", fly)
