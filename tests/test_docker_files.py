"""docker/: no Docker engine runs here, so check what can be checked: every file the Dockerfile copies
exists, its build-time step runs, and every service command is a radseek command whose parser
accepts the options given."""

import re
import subprocess
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
DOCKER = REPO / "docker"


def test_dockerfile_copies_existing_paths_and_its_run_step_works(tmp_path):
    text = (DOCKER / "Dockerfile").read_text()
    for src in re.findall(r"^COPY (.+) \S+$", text, flags=re.M):
        for part in src.split():
            assert (REPO / part).exists(), part
    snippet = re.search(r'RUN python -c "(.+)"', text).group(1).replace("/opt/radseek", str(tmp_path))
    subprocess.run([sys.executable, "-c", snippet], check=True, cwd=REPO)
    assert (tmp_path / "scenario.json").read_text().count("channel_edges_keV") == 1


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
