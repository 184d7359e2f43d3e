"""docker/: no Docker engine runs here, so check what can be checked: every file the Dockerfile copies
exists, its build-time step runs, and every service command is a radseek command whose parser
accepts the options given."""

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
DOCKER = REPO / "docker"


@pytest.mark.io
def test_dockerfile_copies_existing_paths_and_its_run_step_works(tmp_path):
    text = (DOCKER / "Dockerfile").read_text()
    for src in re.findall(r"^COPY (.+) \S+$", text, flags=re.M):
        for part in src.split():
            assert (REPO / part).exists(), part
    snippet = re.search(r'RUN python -c "(.+)"', text).group(1).replace("/opt/radseek", str(tmp_path))
    subprocess.run([sys.executable, "-c", snippet], check=True, cwd=REPO)
    assert (tmp_path / "scenario.json").read_text().count("channel_edges_keV") == 1


@pytest.mark.io
def test_compose_services_run_real_radseek_commands():
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    services = compose["services"]
    assert {"router", "detector", "vehicle", "mission"} <= set(services)
    for name, svc in services.items():
        cmd = svc["command"]
        # argparse reads the options in order and exits 0 at --help only if all before it parsed
        proc = subprocess.run([sys.executable, "-m", "radseek.cli", *cmd, "--help"], capture_output=True, text=True,
                              cwd=REPO, timeout=120)
        assert proc.returncode == 0, f"{name}: {proc.stderr[-500:]}"
        assert proc.stdout.startswith(f"usage: radseek {cmd[0]}"), name
    for svc in services.values():
        for endpoint in re.findall(r"tcp/([\w.]+):7447", " ".join(svc["command"])):
            assert endpoint in ("router", "0.0.0.0"), "inside compose, services reach the router by name"


def _listened_ports(cmd: list[str]) -> set[str]:
    """The ``port/proto`` a service's command listens on (from its own parser where it has one)."""
    name, args = cmd[0], cmd[1:]
    if name == "router":
        proto, hostport = args[args.index("--listen") + 1].split("/", 1)
        return {f"{hostport.rsplit(':', 1)[1]}/{proto}"}
    if name == "vehicle":
        from vehicle_sim.vehicle_cli import build_parser

        a = build_parser().parse_args(args)
        return {f"{a.api_local_port}/udp", f"{a.gcs_local_port}/udp"}
    if name == "mission":
        url = args[args.index("--url") + 1] if "--url" in args else "udpin://0.0.0.0:14540"
        return {f"{url.rsplit(':', 1)[1]}/udp"} if url.startswith("udpin://") else set()
    return set()


def _unsigned_mavlink_on_all_interfaces(cmd: list[str]) -> bool:
    name, args = cmd[0], cmd[1:]
    if name == "vehicle":
        from vehicle_sim.vehicle_cli import build_parser

        a = build_parser().parse_args(args)
        return a.bind not in ("127.0.0.1", "localhost", "::1") and not a.signing_key
    if name == "mission":
        url = args[args.index("--url") + 1] if "--url" in args else "udpin://0.0.0.0:14540"
        return url.startswith("udpin://0.0.0.0") or url.startswith("udpin://[::]")
    return False


def test_compose_publishes_only_listened_ports_on_loopback():
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    for name, svc in compose["services"].items():
        listened = _listened_ports(svc["command"])
        for spec in svc.get("ports", []):
            spec = str(spec)
            port_proto = spec.rsplit(":", 1)[1]
            if "/" not in port_proto:
                port_proto += "/tcp"
            assert spec.startswith("127.0.0.1:"), f"{name}: {spec} is published beyond the host's loopback"
            assert port_proto in listened, f"{name}: publishes {port_proto}, but listens only on {sorted(listened)}"


def test_compose_keeps_unsigned_mavlink_off_every_reachable_network():
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    networks = compose.get("networks") or {}
    for name, svc in compose["services"].items():
        if not _unsigned_mavlink_on_all_interfaces(svc["command"]):
            continue
        joined = svc.get("networks") or ["default"]
        assert not svc.get("ports"), f"{name}: unsigned MAVLink on all interfaces must not publish ports"
        for net in joined:
            assert (networks.get(net) or {}).get("internal") is True, \
                f"{name}: unsigned MAVLink bound to all interfaces on non-internal network {net!r}"
    # the router, on a network the host reaches, is the one service still published (loopback only)
    assert compose["services"]["router"]["ports"] == ["127.0.0.1:7447:7447/tcp"]
