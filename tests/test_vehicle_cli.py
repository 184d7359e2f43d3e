"""``radseek vehicle`` options: SITL defaults, geofence sources, signing key files, bad values."""

import hashlib

import pytest

from radseek_cli import vehicle_cli
from vehicle_sim.link import load_signing_key


def cfg(*argv):
    return vehicle_cli.config_from_args(vehicle_cli.build_parser().parse_args(list(argv)))


def test_defaults_are_px4_sitl_ports_on_loopback():
    c = cfg()
    assert (c.api_port, c.gcs_port, c.api_local_port, c.gcs_local_port) == (14540, 14550, 14580, 18570)
    assert c.bind_host == "127.0.0.1" and c.remote_host == "127.0.0.1"
    assert (c.sysid, c.compid, c.speedup, c.signing_key, c.drop_rate) == (1, 1, 1.0, None, 0.0)
    assert c.fence.xmin == -1000 and c.fence.zmax == 120


def test_geofence_from_bounds_or_scene():
    assert cfg("--bounds=-5,-6,0,5,6,8").fence.ymin == -6
    f = cfg("--scene", "default").fence
    assert f.xmin < 0 < f.xmax and f.zmin == 0
    with pytest.raises(ValueError):
        cfg("--bounds", "1,2,3")


def test_signing_key_files(tmp_path):
    hexkey = tmp_path / "k.hex"
    hexkey.write_text("ab" * 32 + "\n")
    assert load_signing_key(hexkey) == bytes([0xAB]) * 32
    phrase = tmp_path / "k.txt"
    phrase.write_text("correct horse")
    assert load_signing_key(phrase) == hashlib.sha256(b"correct horse").digest()
    assert cfg("--signing-key", str(hexkey)).signing_key == bytes([0xAB]) * 32
    empty = tmp_path / "empty"
    empty.write_text("")
    with pytest.raises(ValueError):
        load_signing_key(empty)


def test_bad_values_exit_with_a_message(capsys):
    assert vehicle_cli.main(["--speedup", "0", "--no-zenoh"]) == 2
    assert "speedup" in capsys.readouterr().err
    assert vehicle_cli.main(["--drop-rate", "1.5", "--no-zenoh", "--api-local-port", "0",
                             "--gcs-local-port", "0"]) == 2


@pytest.mark.io
def test_runs_for_a_fixed_sim_duration(capsys):
    assert vehicle_cli.main(["--no-zenoh", "--api-local-port", "0", "--gcs-local-port", "0", "--api-port", "9",
                             "--gcs-port", "9", "--speedup", "100", "--duration", "5"]) == 0
    out = capsys.readouterr().out
    assert "vehicle ready" in out and "vehicle stopped at t=5.0 s" in out
