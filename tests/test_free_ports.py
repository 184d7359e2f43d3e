"""The tests' port helpers hand out distinct ports: the kernel may give a just-released port again, and a stack
drawn port by port (API, GCS, the vehicle's two local ports) once got its API port twice and failed to start."""

import pytest

from tests.conftest import free_port
from vehicle_sim.harness import free_udp_port

pytestmark = pytest.mark.io  # binds sockets


def test_udp_ports_drawn_in_one_process_are_distinct():
    # 300 draws from ~28,000 ephemeral ports repeat one with probability ~0.8 when drawn blindly
    ports = [free_udp_port() for _ in range(300)]
    assert len(set(ports)) == len(ports)


def test_tcp_ports_drawn_in_one_worker_are_distinct():
    ports = [free_port() for _ in range(300)]
    assert len(set(ports)) == len(ports)
