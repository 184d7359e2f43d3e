"""radseek campaign: sweeps, rows, resume, failures, embedded Ray and an existing loopback Ray cluster."""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from launch.campaign import CHI2_95_2D, Sweep, coverage, fly_error_row, fly_one, open_campaign, parse_effect, summarize
from launch.campaign_store import ROW_GROUP_ROWS, DamagedFile, DamagedStore, load_rows, read_file, salvage, write_rows
from radseek.estimate import SourceEstimate
from radseek_io.outdir import OutputDirError

BIN = Path(sys.executable).parent
#: a fast search: the 9-point lattice cut to 3 dwell points of 1-2 s (a few CPU seconds per flight)
FAST = ["--strategies", "lattice", "--set", "max_dwells=3", "--set", "max_search_dwells=2",
        "--set", "min_search_dwells=1", "--set", "dwell.t_min=1.0", "--set", "dwell.t_max=2.0"]
FAST_PARAMS = {"max_dwells": 3, "max_search_dwells": 2, "min_search_dwells": 1, "dwell.t_min": 1.0,
               "dwell.t_max": 2.0}
ROW_COLUMNS = {"scene", "strategy", "seed", "effect", "error_m", "sigma_m", "covered_95", "dwell_points",
               "mission_time_s", "wall_s", "cpu_s", "radseek_version", "status", "error", "p.max_dwells",
               "p.dwell.t_max"}


# ------------------------------------------------------------------------------------------------ units


def test_effect_spec_parses_name_and_typed_parameters():
    assert parse_effect("none") is None
    assert parse_effect("dead_time") == ("dead_time", {})
    assert parse_effect("wall_attenuation:mu_per_m=0.5, enabled=true") == \
        ("wall_attenuation", {"mu_per_m": 0.5, "enabled": True})
    with pytest.raises(ValueError, match="key=value"):
        parse_effect("dead_time:tau_s")


def test_sweep_is_the_product_with_stable_keys_and_a_seedless_fingerprint(tmp_path):
    s = Sweep(scenes=["default", "outdoor"], strategies=["active", "lattice"], seeds=[0, 1, 2],
              effects=["none", "dead_time:tau_s=2e-5"], params={"max_dwells": [8, 16], "dwell.t_max": 10.0})
    flights = s.flights()
    assert len(flights) == 2 * 2 * 2 * 2 * 3 == len({f["key"] for f in flights})
    assert [f["seed"] for f in flights[:16]] == [0] * 16  # every case gets seed 0 first
    more = Sweep(**{**s.to_dict(), "seeds": [0, 1, 2, 3]})
    assert more.fingerprint() == s.fingerprint()  # more seeds: the same campaign, resumed
    assert {f["key"] for f in s.flights()} <= {f["key"] for f in more.flights()}
    other = Sweep(**{**s.to_dict(), "params": {"max_dwells": [8, 16], "dwell.t_max": 12.0}})
    assert other.fingerprint() != s.fingerprint()
    with pytest.raises(ValueError, match="unknown parameter"):
        Sweep(params={"dwell.t_maxx": 1.0})
    with pytest.raises(ValueError, match="unknown strategy"):
        Sweep(strategies=["spiral"])
    toml = tmp_path / "sweep.toml"
    toml.write_text('[sweep]\nscenes = ["default"]\nseeds = {start = 5, stop = 8}\n'
                    '[sweep.params]\n"next_best.gain_kind" = ["eq6", "eq6_pose"]\n"odometry.sigma_xy" = 0.01\n')
    t = Sweep.from_toml(toml)
    assert t.seeds == [5, 6, 7] and len(t.cases()) == 2


def test_coverage_is_the_95_percent_ellipse_of_the_xy_covariance():
    est = SourceEstimate(0.0, 0.0, 0.0, 1000.0, 30.0, [[0.04, 0, 0], [0, 0.01, 0], [0, 0, 1.0]])  # sigmas 0.2, 0.1
    d2, covered = coverage(est, (0.2, 0.0))
    assert d2 == pytest.approx(1.0) and covered
    r = math.sqrt(CHI2_95_2D)  # on the 95 % ellipse along each axis
    assert coverage(est, (0.0, 0.1 * r * 0.999))[1] and not coverage(est, (0.0, 0.1 * r * 1.001))[1]
    assert not coverage(est.replace(covariance=np.zeros((3, 3))), (0.01, 0))[1]  # collapsed ellipse
    assert coverage(None, (0, 0)) == (pytest.approx(math.nan, nan_ok=True), None)


def test_a_failing_flight_is_a_row_with_its_error():
    s = Sweep(scenes=["default"], strategies=["lattice"], seeds=[0], effects=["dead_time:tau_s=-1"],
              params=FAST_PARAMS)
    row = fly_one(s.flights()[0])
    assert row["status"] == "error" and "tau_s" in row["error"]
    assert row["scene"] == "default" and row["seed"] == 0 and row["p.max_dwells"] == 3


def test_one_flight_row_has_the_figures():
    s = Sweep(scenes=["default"], strategies=["lattice"], seeds=[3], params=FAST_PARAMS)
    row = fly_one(s.flights()[0])
    assert row["status"] == "ok", row["error"]
    assert row["dwell_points"] == 3 and row["mission_time_s"] > 0 and row["wall_s"] > 0
    assert math.isfinite(row["error_m"]) and row["error_m"] == pytest.approx(
        math.hypot(row["est_x"] - row["true_x"], row["est_y"] - row["true_y"]))
    assert isinstance(row["covered_95"], bool)
    if "est.ellipse_95.a_m" in row:  # the estimator's own 95 % ellipse is the one covered_95 tests
        assert row["est.ellipse_95.a_m"] == pytest.approx(row["sigma_m"] * math.sqrt(CHI2_95_2D), rel=1e-6)
    assert summarize([row])[0]["estimated"] == 1


def test_output_folder_holds_one_sweep(tmp_path):
    s = Sweep(scenes=["default"], seeds=[0])
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(OutputDirError, match="holds no campaign"):
        open_campaign(s, tmp_path)
    out = tmp_path / "c"
    open_campaign(s, out)
    (out / "campaign.json").write_text(json.dumps({"fingerprint": s.fingerprint()}))
    assert open_campaign(Sweep(scenes=["default"], seeds=[0, 1]), out) == out  # same sweep: resume
    with pytest.raises(OutputDirError, match="another sweep"):
        open_campaign(Sweep(scenes=["outdoor"], seeds=[0]), out)
    open_campaign(Sweep(scenes=["outdoor"], seeds=[0]), out, force=True)
    assert not (out / "campaign.json").exists()


# ------------------------------------------------------------------------------------------------ damaged store


def _recorded(tmp_path: Path, seeds: int) -> tuple[Sweep, Path, list[dict]]:
    """A campaign folder as a finished run leaves it: campaign.json and a merged flights.parquet (rows of the
    driver's own row builder, each with a distinct number)."""
    sweep = Sweep(scenes=["default"], strategies=["lattice"], seeds=list(range(seeds)), params=FAST_PARAMS)
    out = open_campaign(sweep, tmp_path / "c")
    (out / "campaign.json").write_text(json.dumps({"fingerprint": sweep.fingerprint()}))
    rows = [{**fly_error_row(f), "error_m": 0.01 * f["seed"]} for f in sweep.flights()]
    write_rows(out / "flights.parquet", rows)
    return sweep, out, rows


def _chunk_end(path: Path, group: int, column: str) -> int:
    """The offset of the last byte of ``column``'s chunk in row group ``group`` (inside its data page)."""
    meta = pq.ParquetFile(path).metadata
    j = [meta.schema.column(i).name for i in range(meta.num_columns)].index(column)
    c = meta.row_group(group).column(j)
    return (c.dictionary_page_offset or c.data_page_offset) + c.total_compressed_size - 1


def _flip(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


def _empty(path: Path) -> str:
    path.write_bytes(b"")
    return "0 bytes"


def _truncated(path: Path) -> str:
    path.write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
    return "truncated"


def _corrupted(path: Path) -> str:
    _flip(path, _chunk_end(path, 1, "error_m"))
    return "corrupted bytes in row group 2 of 3"


@pytest.mark.parametrize("damage", [_empty, _truncated, _corrupted])
def test_a_damaged_flights_file_is_named_in_one_line_and_left_as_it_is(tmp_path, capsys, damage):
    from radseek_cli.campaign_cli import main

    sweep, out, rows = _recorded(tmp_path, 2 * ROW_GROUP_ROWS + 6)
    what = damage(out / "flights.parquet")
    before = (out / "flights.parquet").read_bytes()
    code = main(["--scenes", "default", "--seeds", str(2 * ROW_GROUP_ROWS + 6), *FAST, "--out", str(out), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert str(out / "flights.parquet") in err and what in err and "--salvage" in err, err
    assert "Traceback" not in err and "rerun with --salvage" in err
    assert (out / "flights.parquet").read_bytes() == before and sorted(p.name for p in out.iterdir()) == [
        "campaign.json", "flights.parquet"]
    # what --salvage does before it flies (run_campaign; flown again end to end on the token cluster test's cluster):
    # the file moved aside as it was, its readable rows kept, and exactly the other flights left to fly
    with pytest.raises(DamagedStore) as exc:
        load_rows(out)
    (damaged,) = exc.value.damaged
    assert salvage(out, damaged).read_bytes() == before
    kept = {r["key"] for r in load_rows(out)}
    todo = {f["key"] for f in sweep.flights()} - kept
    assert kept == ({r["key"] for r in rows[:ROW_GROUP_ROWS] + rows[2 * ROW_GROUP_ROWS:]} if damage is _corrupted
                    else set()) and todo == {r["key"] for r in rows} - kept


def test_corrupted_bytes_cost_only_their_row_group_and_salvage_keeps_the_rest(tmp_path):
    sweep, out, rows = _recorded(tmp_path, 2 * ROW_GROUP_ROWS + 6)
    path = out / "flights.parquet"
    _flip(path, _chunk_end(path, 1, "error_m"))  # one bit of one number: a plain read returns a wrong value
    plain = pq.read_table(path).to_pylist()
    assert sum(a["error_m"] != b["error_m"] for a, b in zip(plain, rows, strict=True)) == 1
    damaged_bytes = path.read_bytes()
    with pytest.raises(DamagedStore, match=f"{ROW_GROUP_ROWS + 6} of {2 * ROW_GROUP_ROWS + 6} rows readable"):
        load_rows(out)  # the page checksum catches it
    got = read_file(path)
    assert isinstance(got, DamagedFile) and "CRC" in got.problem
    lost = {r["key"] for r in rows[ROW_GROUP_ROWS:2 * ROW_GROUP_ROWS]}
    assert {r["key"] for r in got.rows} == {r["key"] for r in rows} - lost
    assert all(r["error_m"] == by["error_m"] for r, by in zip(got.rows, [x for x in rows if x["key"] not in lost],
                                                              strict=True))
    aside = salvage(out, got)
    assert aside == out / "flights.parquet.damaged" and aside.read_bytes() == damaged_bytes  # kept, not deleted
    kept = load_rows(out)
    assert {r["key"] for r in kept} == {r["key"] for r in rows} - lost
    todo = [f for f in sweep.flights() if f["key"] not in {r["key"] for r in kept}]
    assert {f["key"] for f in todo} == lost  # a resume flies exactly the lost flights


def test_a_damaged_part_file_is_moved_beside_the_parts_not_into_them(tmp_path):
    _, out, rows = _recorded(tmp_path, 3)
    (out / "parts").mkdir()
    part = out / "parts" / "part-00000000000000000001-1-00001.parquet"
    write_rows(part, rows[:2])
    _truncated(part)
    with pytest.raises(DamagedStore, match="part-00000000000000000001-1-00001.parquet is damaged"):
        load_rows(out)
    got = read_file(part)
    assert isinstance(got, DamagedFile) and got.rows == [] and got.total_rows is None
    assert salvage(out, got) == out / f"{part.name}.damaged"  # the parts folder is removed after a merge
    assert {r["key"] for r in load_rows(out)} == {r["key"] for r in rows}


# ------------------------------------------------------------------------------------------------ Ray


def _campaign(*args: str, env: dict | None = None, timeout: float = 500) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "radseek"), "campaign", *args], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, **(env or {})})


def _rows(out: Path) -> list[dict]:
    return pq.read_table(out / "flights.parquet").to_pylist()


# Ray: a local cluster takes fixed default ports of its own (dashboard agent, metrics): the two clusters are
# started one at a time on this machine, whichever pytest worker runs them (conftest: exclusive)
RAY_GROUP = pytest.mark.exclusive("ray-cluster")
#: the flights of a test's cluster at the same nice level as the test suite's other work: Ray's default 15 (a
#: campaign yields the CPU to everything else on a shared machine) left them a few % of a core next to the other
#: pytest worker; the embedded campaigns get it from --niceness, a `ray start` head from Ray's own variable
FAIR = {"RAY_worker_niceness": "0"}
#: a client Ray refuses for its token retries the connection 20 times, a second apart, before it gives up; the
#: refusal is not transient, so one attempt (Ray's own knob for the GCS connect budget) gives the same error
ONE_ATTEMPT = {"RAY_gcs_server_port_wait_time_s": "1"}


@pytest.mark.slow
@pytest.mark.io
@RAY_GROUP
def test_embedded_campaign_writes_rows_records_failures_and_resumes(tmp_path, capsys):
    """The run that flies starts an embedded Ray of its own (``radseek campaign`` as a user runs it); the steps that
    fly nothing (a rerun, another sweep, a damaged file) are the same CLI called in this process: each start-up of
    the command costs ~3 s of CPU, a Ray of one worker ~6 s more and each further worker ~1.5 s (flights of this size
    ~0.3 s each once a worker runs). Resuming with one more seed and salvaging a damaged file fly again: they do it
    on test_campaign_on_an_existing_loopback_token_cluster's cluster (two embedded Rays fewer: 40 to 22 s of CPU).
    Two workers: test_kill_9_..., a two-CPU cluster: test_campaign_on_an_existing_loopback_token_cluster.
    """
    from radseek_cli.campaign_cli import main

    out = tmp_path / "c"

    def args(seeds: str) -> list[str]:
        return ["--scenes", "default", "outdoor", "--seeds", seeds, *FAST, "--effect", "none",
                "--effect", "dead_time:tau_s=-1", "--workers", "1", "--niceness", "0", "--out", str(out)]

    def in_process(argv: list[str]) -> tuple[int, str, str]:
        capsys.readouterr()
        code = main(argv)
        got = capsys.readouterr()
        return code, got.out, got.err

    r = _campaign(*args("2"))
    assert r.returncode == 0, r.stderr
    rows = _rows(out)
    assert len(rows) == 8 and ROW_COLUMNS <= set(rows[0])
    ok = [x for x in rows if x["status"] == "ok"]
    bad = [x for x in rows if x["status"] != "ok"]
    assert {(x["scene"], x["seed"]) for x in ok} == {(s, k) for s in ("default", "outdoor") for k in (0, 1)}
    assert all(x["dwell_points"] == 3 and math.isfinite(x["error_m"]) for x in ok)
    assert len(bad) == 4 and all("tau_s" in x["error"] for x in bad)  # recorded, not fatal
    assert {x["radseek_version"] for x in rows} == {__import__("radseek").__version__}
    summary = (out / "summary.md").read_text()
    assert summary.count("| default | lattice | none |") == 1 and "## Failed flights" in summary
    assert (out / "error_vs_dwells.png").stat().st_size > 0 and (out / "coverage.png").stat().st_size > 0
    first = {x["key"]: x["finished_at"] for x in rows}

    code, stdout, err = in_process(args("2"))  # rerun: nothing left to fly
    assert code == 0, err
    assert "0 flights flown, 8 already recorded" in stdout
    assert {x["key"]: x["finished_at"] for x in _rows(out)} == first

    code, _, err = in_process(["--scenes", "default", "--seeds", "1", *FAST, "--out", str(out)])  # another sweep
    assert code == 2 and "--force" in err

    damaged = (out / "flights.parquet").read_bytes()[:-100]  # truncated: no footer, no row readable
    (out / "flights.parquet").write_bytes(damaged)
    code, _, err = in_process(args("1"))
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "flights.parquet is damaged (truncated" in err and "--salvage" in err
    assert (out / "flights.parquet").read_bytes() == damaged


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _pids_of(temp_dir: str) -> set[int]:
    """Processes whose command line names ``temp_dir`` (the cluster this test started), and their children."""
    mine: set[int] = set()
    parents: dict[int, int] = {}
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            if temp_dir.encode() in (p / "cmdline").read_bytes():
                mine.add(int(p.name))
            parents[int(p.name)] = int((p / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
    grew = True
    while grew:
        kids = {pid for pid, ppid in parents.items() if ppid in mine} - mine
        mine |= kids
        grew = bool(kids)
    return mine


def _listening(port: int) -> list[str]:
    """Local addresses listening on ``port`` (hex, from /proc/net/tcp and tcp6)."""
    found = []
    for f in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(f).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            if state == "0A" and int(local.rsplit(":", 1)[1], 16) == port:
                found.append(local.rsplit(":", 1)[0])
    return found


LOOPBACK_HEX = {"0100007F", "0000000000000000FFFF00000100007F", "00000000000000000000000001000000"}


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            if Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
                alive.add(pid)
        except (OSError, IndexError):
            pass
    return alive


def _stop(pids: set[int]) -> None:
    """SIGTERM the given processes, SIGKILL what is left after 15 s (gcs_server may ignore SIGTERM)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in _alive(pids):
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + 15
        while _alive(pids) and time.monotonic() < deadline:
            time.sleep(0.3)


def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent, start time) of a process, None if gone."""
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return f[0], int(f[1]), int(f[19])
    except (OSError, IndexError, ValueError):
        return None


def _tree(root: int) -> dict[int, tuple[int, str]]:
    """``root``'s descendants now: pid -> (start time, command line)."""
    parents = {}
    for p in Path("/proc").iterdir():
        if p.name.isdigit() and (st := _stat(int(p.name))) is not None:
            parents[int(p.name)] = st[1]
    mine, grew = {root}, True
    while grew:
        kids = {pid for pid, ppid in parents.items() if ppid in mine} - mine
        mine |= kids
        grew = bool(kids)
    out = {}
    for pid in mine - {root}:
        st = _stat(pid)
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if st is not None:
            out[pid] = (st[2], cmd)
    return out


def _survivors(procs: dict[int, tuple[int, str]]) -> dict[int, str]:
    """Those of ``procs`` still running (the same process: same start time; a zombie has ended)."""
    return {pid: cmd for pid, (start, cmd) in procs.items()
            if (st := _stat(pid)) is not None and st[2] == start and st[0] not in "ZX"}


@pytest.mark.slow
@pytest.mark.io
@RAY_GROUP
def test_kill_9_of_a_campaign_leaves_no_ray_process_and_no_temporary_folder(tmp_path):
    proc = subprocess.Popen([str(BIN / "radseek"), "campaign", "--scenes", "default", "--seeds", "60", *FAST,
                             "--workers", "2", "--out", str(tmp_path / "c"), "-q"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    tree: dict[int, tuple[int, str]] = {}
    try:
        deadline = time.monotonic() + 240
        while not any("ray::fly_one" in cmd for _, cmd in tree.values()):  # the cluster is flying flights
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, sorted(cmd[:60] for _, cmd in tree.values())
            time.sleep(0.3)
            tree = _tree(proc.pid)
        tree = _tree(proc.pid)
        cmds = " ".join(cmd for _, cmd in tree.values())
        assert "ray::DashboardAgent" in cmds and "ray::RuntimeEnvAgent" in cmds and "raylet" in cmds, cmds
        temp = re.search(r"/tmp/radseek-ray-[A-Za-z0-9_]+", cmds).group(0)
        assert Path(temp).is_dir()
        proc.kill()
        proc.wait()
        deadline = time.monotonic() + 60
        while (_survivors(tree) or Path(temp).exists()) and time.monotonic() < deadline:
            time.sleep(0.5)
        assert not _survivors(tree), _survivors(tree)
        assert not Path(temp).exists(), sorted(p.name for p in Path(temp).iterdir())
        later = {pid: cmd for pid, cmd in _pids_cmdlines().items() if temp in cmd}  # started after the snapshot
        assert not later, later
    finally:
        proc.kill()
        for pid in _survivors(tree):
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _pids_cmdlines() -> dict[int, str]:
    out = {}
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                out[int(p.name)] = (p / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                pass
    return out


@pytest.mark.io
def test_an_address_where_nothing_listens_is_named_at_once(tmp_path):
    port = _free_port()
    r = _campaign("--address", f"127.0.0.1:{port}", "--scenes", "default", "--seeds", "1", *FAST,
                  "--out", str(tmp_path / "c"), timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"no Ray cluster at 127.0.0.1:{port}: nothing listens there (Connection refused)" in r.stderr


def _client_env(home: Path, **auth: str) -> dict[str, str]:
    """The environment of a client with only the given Ray authentication variables (and a home without a token)."""
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_AUTH_MODE", "RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")}
    return {**env, "HOME": str(home), "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0", **auth}


@pytest.mark.slow
@pytest.mark.io
@RAY_GROUP
def test_campaign_on_an_existing_loopback_token_cluster(tmp_path):
    """One `ray start --head` as Ray 2.60 starts it (token auth on), bound to loopback: a client without its token,
    or with another, is told in one line what to set; with it, the campaign flies on the cluster's CPUs, resumes
    with one more seed (only its flights flown) and salvages a damaged flights file; stopping the head leaves no Ray
    process. (One cluster for both: each `ray start` costs a worker 10-15 s.)"""
    temp_dir = f"/tmp/rsk-tok-{os.getpid()}-{time.time_ns() % 10**6}"  # short: Ray's socket paths
    port, token = _free_port(), secrets.token_hex(32)
    head = _client_env(tmp_path, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token, **FAIR)
    start = subprocess.run([str(BIN / "ray"), "start", "--head", "--node-ip-address", "127.0.0.1",
                            "--port", str(port), "--include-dashboard=false", "--num-cpus", "2",
                            "--temp-dir", temp_dir, "--disable-usage-stats"],
                           capture_output=True, text=True, timeout=180, env=head)
    try:
        assert start.returncode == 0, start.stdout + start.stderr
        assert _listening(port) and set(_listening(port)) <= LOOPBACK_HEX, _listening(port)

        def campaign(out: str, env: dict[str, str], *scenes: str, seeds: str = "1") -> subprocess.CompletedProcess:
            scenes_, extra = [x for x in scenes if not x.startswith("--")], [x for x in scenes if x.startswith("--")]
            args = ["--address", f"127.0.0.1:{port}", "--scenes", *(scenes_ or ["default"]), "--seeds", seeds, *FAST,
                    *extra]
            return subprocess.run([str(BIN / "radseek"), "campaign", *args, "--out", str(tmp_path / out)],
                                  capture_output=True, text=True, timeout=500, env=env)

        r = campaign("none", _client_env(tmp_path, **ONE_ATTEMPT))
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert f"the Ray cluster at 127.0.0.1:{port} wants a token" in r.stderr
        assert "set RAY_AUTH_MODE=token" in r.stderr and "RAY_AUTH_TOKEN" in r.stderr, r.stderr
        r = campaign("wrong", _client_env(tmp_path, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32),
                                          **ONE_ATTEMPT))
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "refused this client's token" in r.stderr, r.stderr
        env = _client_env(tmp_path, RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=token)  # what it said
        r = campaign("right", env, "default", "outdoor")
        assert r.returncode == 0, r.stderr
        rows = _rows(tmp_path / "right")
        assert len(rows) == 2 and all(x["status"] == "ok" for x in rows), rows
        assert "2 flights flown" in r.stdout and "on 2 CPUs" in r.stdout
        first = {x["key"]: x["finished_at"] for x in rows}
        r = campaign("right", env, "default", "outdoor", seeds="2")  # one more seed: only seed 1 is flown
        assert r.returncode == 0, r.stderr
        assert "2 flights flown, 2 already recorded" in r.stdout, r.stdout
        rows = _rows(tmp_path / "right")
        assert len(rows) == 4 and {x["key"]: x["finished_at"] for x in rows if x["key"] in first} == first
        damaged = (tmp_path / "right" / "flights.parquet").read_bytes()[:-100]  # truncated: no footer
        (tmp_path / "right" / "flights.parquet").write_bytes(damaged)
        r = campaign("right", env, "default", "outdoor", "--salvage")  # seed 0 only: its 2 flights flown again
        assert r.returncode == 0, r.stderr
        assert "2 flights flown, 0 already recorded" in r.stdout and "moved it to" in r.stderr, r.stdout + r.stderr
        assert (tmp_path / "right" / "flights.parquet.damaged").read_bytes() == damaged
        assert len(_rows(tmp_path / "right")) == 2
    finally:
        pids = _pids_of(temp_dir)
        _stop(pids)
        subprocess.run(["rm", "-rf", temp_dir], check=False)
    assert pids and not _alive(pids)

