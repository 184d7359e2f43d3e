"""A MAVLink port that cannot be opened is a clear connection error naming the URL and what to do, not a
MAVSDK traceback (a second `radseek run` beside a first one got "mission failed (exit 1)")."""

import asyncio
import socket

import pytest

from mission.client.connection import ConnectionFailed, ConnectionResult, connect


@pytest.mark.io
def test_a_taken_port_is_a_named_connection_error():
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        taken.bind(("0.0.0.0", 0))  # a real socket holds the port, as another run's MAVSDK would
        url = f"udpin://0.0.0.0:{taken.getsockname()[1]}"
        with pytest.raises(ConnectionFailed) as err:
            asyncio.run(connect(url, timeout_s=2.0))
    finally:
        taken.close()
    assert err.value.result is ConnectionResult.NO_LINK
    assert url in str(err.value) and "--mavlink-port" in str(err.value)


def test_run_prints_the_missions_own_error(tmp_path):
    from launch.stack import _last_words

    log = tmp_path / "mission.log"
    log.write_text("Traceback ...\nradseek mission: cannot open the MAVLink link: udpin://0.0.0.0:14540: BIND_ERROR\n")
    assert _last_words(log) == ": radseek mission: cannot open the MAVLink link: udpin://0.0.0.0:14540: BIND_ERROR"
    log.write_text("Traceback ...\nKeyError: 'x'\n")
    assert _last_words(log) == ""
    assert _last_words(tmp_path / "missing.log") == ""
