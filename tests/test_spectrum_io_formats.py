"""The readers added for issue 32 (radseek_io.spectrum_io), on real public files: RadiaCode .rcspg, radiacode-tools
NDJSON logs, RadiaCode XML with an embedded background, RadiaCode JSON; the CSV variants; bad input; the
``radseek spectra show`` and NDJSON ``import-flight`` commands (sources and licences: tests/data/real-spectra)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from radseek_cli import flight_cli
from radseek_io import spectrum_io as sio
from radseek_io.dataset import read_dataset
from radseek_io.spectrum_io import ndjson, rcspg

DATA = Path(__file__).resolve().parent / "data" / "real-spectra"
K40 = DATA / "K40.rcspg"
WALK = DATA / "walk_rc103_gnss.ndjson"
XRAY = DATA / "xray_rc103.ndjson"
TH = DATA / "data_th232_plus_background.xml"
REPO = Path(__file__).resolve().parent.parent


# ------------------------------------------------------------------------------------------------ .rcspg


def test_rcspg_rows_and_accumulated_row_told_apart():
    hdr = rcspg.read_header(K40)
    rows = list(rcspg.iter_rows(K40, hdr))
    assert len(rows) == 690 and hdr.serial == "RC-102-001272" and hdr.channels == 1024
    durations = np.array([r.duration_s for r in rows])
    # the header's accumulation time is the sum of the rows' durations (43,510 s), not the accumulated row's
    assert durations.sum() == hdr.accumulation_s == 43510
    assert hdr.accumulated.livetime == 1586387 and hdr.accumulated.kind == "accumulated"
    # one-minute rows, and one row of 1563 s where the recording was interrupted (Flags 0)
    assert np.median(durations) == 60 and durations.max() == 1563 and hdr.flags == "0"
    # the accumulated row holds the device's history: every channel at least the recording's counts
    total = np.sum([r.counts for r in rows], axis=0)
    assert total.sum() == 249362
    assert np.all(hdr.accumulated.counts >= total)
    assert hdr.accumulated.counts.sum() > 6000 * total.sum()
    # row timestamps are the rows' ends: the first ends one duration after the header's start
    assert rows[0].end_s - hdr.start_s == pytest.approx(rows[0].duration_s, abs=1.0)
    assert hdr.calibration == pytest.approx((-12.994064, 2.4500299, 3.3654124e-4), rel=1e-6)


def test_rcspg_through_read_spectra():
    fg, acc = sio.read_spectra(K40)
    assert (fg.kind, acc.kind) == ("foreground", "accumulated")
    assert fg.livetime == 43510 and fg.counts.sum() == 249362 and fg.meta["rows"] == 690
    assert fg.start_time == "2023-12-01T08:16:11Z"  # FILETIME is UTC; the header's "Time" 00:16:11 is local
    assert fg.realtime == pytest.approx(43512.3, abs=0.1)
    # K-40's 1461 keV line is where the calibration puts it: the rate above background peaks within 3 % of it
    e = fg.edges_keV()
    centre = 0.5 * (e[1:] + e[:-1])
    sel = (centre > 1300) & (centre < 1650)
    smooth = np.convolve(fg.counts, np.ones(15) / 15, mode="same")
    assert abs(centre[sel][np.argmax(smooth[sel])] - 1461) < 0.03 * 1461


@pytest.mark.parametrize("path", [K40, WALK])
def test_streamed_formats_peak_below_twice_the_file(path):
    tracemalloc.start()
    try:
        sio.read_spectra(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 2 * path.stat().st_size, peak


# ------------------------------------------------------------------------------------------------ NDJSON


def test_ndjson_walk_frames_resets_and_gnss():
    lines = [json.loads(x) for x in WALK.read_text().splitlines()]
    spectra = [r for r in lines if "counts" in r]
    log = ndjson.scan(WALK)
    assert log.spectrum_records == len(spectra) == 83 and log.serial == "RC-103-000070"
    # record 2 is a device reset (counts and duration drop to 0), record 3 comes 587 s later with a duration
    # 6549 s on: neither gives a frame; the 80 five-second polls after it do
    assert (log.resets, log.timing_breaks, log.frames) == (1, 1, 80)
    assert spectra[1]["duration"] == 0 and spectra[2]["duration"] == 6549
    # the frames add up to the last cumulative spectrum minus the one they start from
    np.testing.assert_array_equal(log.foreground, np.subtract(spectra[-1]["counts"], spectra[2]["counts"]))
    assert log.frame_live_s == pytest.approx(spectra[-1]["timestamp"] - spectra[2]["timestamp"])
    assert log.frame_live_s == pytest.approx(spectra[-1]["duration"] - spectra[2]["duration"], abs=1.5)
    fixes = [r for r in lines if r.get("gnss") is True]
    assert len(log.gnss) == len(fixes) == 406
    assert log.gnss[0].lat == fixes[0]["lat"] and log.gnss[0].alt == fixes[0]["alt"]
    # gpsd's sep (95 % spherical) is the only position quality in this log: sigma = sep / 2.8
    assert log.gnss[0].sigma_h == pytest.approx(fixes[0]["sep"] / 2.80)
    assert log.device_records == {"RealTimeData": 403, "DoseRateDB": 4, "RareData": 3}


def test_ndjson_without_breaks_frames_sum_to_last_minus_first():
    recs = [json.loads(x) for x in XRAY.read_text().splitlines()]
    fg, acc = sio.read_spectra(XRAY)
    assert fg.meta["frames"] == len(recs) - 1
    np.testing.assert_array_equal(fg.counts, np.subtract(recs[-1]["counts"], recs[0]["counts"]))
    assert acc.livetime == recs[-1]["duration"] and acc.counts.sum() == sum(recs[-1]["counts"])


def test_ndjson_irregular_timing_never_crashes(tmp_path):
    recs = [json.loads(x) for x in XRAY.read_text().splitlines()][:12]
    order = [0, 1, 2, 2, 4, 3, 5, 6, 8, 9, 10, 11]  # a duplicate, a swap, a dropped poll (7)
    lines = [json.dumps(recs[i]) for i in order]
    reset = dict(recs[9], counts=[0] * 1024, duration=0.0, timestamp=recs[9]["timestamp"] + 0.5)
    lines.insert(10, json.dumps(reset))
    lines.append('{"timestamp": 17374')  # a logger killed mid-write
    f = tmp_path / "irregular.ndjson"
    f.write_text("\n".join(lines) + "\n")
    log = ndjson.scan(f)
    assert log.out_of_order == 2  # the duplicate and the record older than the one before
    assert log.resets >= 1 and log.frames >= 5
    assert any("cut off" in n for n in log.notes)
    assert np.all(log.foreground >= 0)


def test_ndjson_refuses_bad_values_naming_the_line(tmp_path):
    rec = json.loads(XRAY.read_text().splitlines()[0])
    for field, value, expect in (("counts", [1e300] + [0] * 1023, "channel 0"), ("duration", 1e29, "duration"),
                                 ("timestamp", "soon", "timestamp"), ("calibration", [0, -1, 0], "calibration")):
        f = tmp_path / f"bad_{field}.ndjson"
        f.write_text(json.dumps(rec) + "\n" + json.dumps(dict(rec, **{field: value})) + "\n" + json.dumps(rec) + "\n")
        with pytest.raises(sio.SpectrumFileError, match=f"line 2.*{expect}"):
            sio.read_spectra(f)
    f = tmp_path / "nan.ndjson"
    f.write_text(json.dumps(rec) + "\n" + json.dumps(rec).replace('"duration": 175.0', '"duration": NaN') + "\n{}\n")
    with pytest.raises(sio.SpectrumFileError, match="line 2"):
        sio.read_spectra(f)


# ------------------------------------------------------------------------------------------------ XML, JSON


def test_radiacode_xml_embedded_background():
    fg, bg = sio.read_spectra(TH)
    assert (fg.kind, bg.kind) == ("foreground", "background")
    assert (fg.livetime, bg.livetime) == (172800, 127800)
    assert (fg.title, bg.title) == ("Th-232-BG", "BG 35hr")
    # each layer keeps its own StartTime (the file has one per layer)
    assert (fg.start_time, bg.start_time) == ("2023-10-17T22:30:56", "2023-09-15T18:58:27")
    assert fg.counts.sum() == 26474139 and bg.counts.sum() == 450876
    # the background is a background: its rate is a small fraction of the thorium source's
    assert bg.counts.sum() / bg.livetime < 0.03 * fg.counts.sum() / fg.livetime


def test_radiacode_json_documents(tmp_path):
    """Synthetic files from the documented radiacode-tools schemas (RcSpectrum.as_dict and an rcmultispg
    record; no public RadiaCode phone-app JSON export was found to test on)."""
    fg, bg = sio.read_spectra(TH)
    doc = {"fg": {"spectrum_name": fg.title, "device_model": "RadiaCode-102", "serial_number": fg.serial,
                  "calibration": {"a0": fg.calibration[0], "a1": fg.calibration[1], "a2": fg.calibration[2]},
                  "timestamp": "2023-10-17T22:30:56", "duration": fg.livetime, "channels": 1024,
                  "counts": [int(c) for c in fg.counts], "comment": ""},
           "bg": {"spectrum_name": bg.title, "device_model": "RadiaCode-102", "serial_number": bg.serial,
                  "calibration": list(bg.calibration), "timestamp": "2023-09-15T18:58:27",
                  "duration": bg.livetime, "channels": 1024, "counts": [int(c) for c in bg.counts]},
           "note": ""}
    f = tmp_path / "th.json"
    f.write_text(json.dumps(doc))
    a, b = sio.read_spectra(f)
    np.testing.assert_array_equal(a.counts, fg.counts)
    np.testing.assert_array_equal(b.counts, bg.counts)
    assert (a.kind, b.kind, b.livetime) == ("foreground", "background", 127800)
    rec = XRAY.read_text().splitlines()[0]
    g = tmp_path / "record.json"
    g.write_text(rec)
    (sp,) = sio.read_spectra(g)
    assert sp.kind == "accumulated" and sp.livetime == json.loads(rec)["duration"]
    doc["fg"]["channels"] = 1000
    f.write_text(json.dumps(doc))
    with pytest.raises(sio.SpectrumFileError, match="fg channels"):
        sio.read_spectra(f)


NPES = REPO / "tests" / "data" / "npes" / "example1_radiacode101.json"


def test_npes_json_of_a_real_radiacode_101(tmp_path):
    """The NPES-JSON project's example 1 (MIT): a RadiaCode-101 spectrum and its background as Gamma MCA saved them
    (NPESv2, 256 channels, no calibration). Each spectrum's counts add up to the file's own validPulseCount, the
    live time is its measurementTime, the channels stay channel numbers; the same package as an NPESv1 document
    reads the same. Before this reader the file failed ('neither an RcSpectrum document nor a spectrum record')."""
    doc = json.loads(NPES.read_text())
    fg, bg = sio.read_spectra(NPES)
    res = doc["data"][0]["resultData"]
    for sp, kind, key in ((fg, "foreground", "energySpectrum"), (bg, "background", "backgroundEnergySpectrum")):
        d = res[key]
        assert sp.kind == kind and sp.n_channels == d["numberOfChannels"] == 256
        np.testing.assert_array_equal(sp.counts, d["spectrum"])
        assert sp.counts.sum() == d["validPulseCount"] and sp.livetime == d["measurementTime"]
        np.testing.assert_array_equal(sp.edges_keV(), np.arange(257))
        assert sp.meta["device"] == "RadiaCode-101"
    assert (fg.livetime, bg.livetime, fg.counts.sum(), bg.counts.sum()) == (86843, 86516, 60800, 30266)
    assert fg.start_time == res["startTime"] and bg.start_time is None
    # foreground and background not swapped: the sample ("Mushrooms") adds to the room's rate
    assert fg.counts.sum() / fg.livetime > 1.5 * bg.counts.sum() / bg.livetime
    one = tmp_path / "v1.json"
    one.write_text(json.dumps(dict(doc["data"][0], schemaVersion="NPESv1")))
    a, b = sio.read_spectra(one)
    np.testing.assert_array_equal(a.counts, fg.counts)
    np.testing.assert_array_equal(b.counts, bg.counts)


@pytest.mark.parametrize("change, field", [
    (lambda e: e.pop("measurementTime"), "energySpectrum.measurementTime"),
    (lambda e: e.update(numberOfChannels=1024), "energySpectrum.numberOfChannels"),
    (lambda e: e.update(energyCalibration={"polynomialOrder": 1, "coefficients": [1.0, 3.0, 0.001]}),
     "energySpectrum.energyCalibration.polynomialOrder"),
    (lambda e: e.update(energyCalibration={"polynomialOrder": 1, "coefficients": [5.0, -3.0]}), "does not rise"),
    (lambda e: e["spectrum"].__setitem__(3, -1), "channel 3"),
])
def test_npes_bad_values_refused_naming_the_field(tmp_path, change, field):
    doc = json.loads(NPES.read_text())
    change(doc["data"][0]["resultData"]["energySpectrum"])
    f = tmp_path / "bad.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(sio.SpectrumFileError, match=rf"bad\.json: data\[0\]\.resultData\..*{field}"):
        sio.read_spectra(f)


def test_npes_calibration_lowest_order_first(tmp_path):
    doc = json.loads(NPES.read_text())
    doc["data"][0]["resultData"]["energySpectrum"]["energyCalibration"] = {
        "polynomialOrder": 2, "coefficients": [-3.5, 12.0, 0.004]}
    f = tmp_path / "cal.json"
    f.write_text(json.dumps(doc))
    fg, bg = sio.read_spectra(f)
    assert fg.calibration == (-3.5, 12.0, 0.004) and bg.calibration == (0.0, 1.0)
    assert fg.edges_keV()[100] == pytest.approx(-3.5 + 1200 + 40)


# ------------------------------------------------------------------------------------------------ CSV


def _csv(tmp_path, text, name="s.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_csv_channel_column_honoured(tmp_path):
    sp = sio.read_spectrum(_csv(tmp_path, "# live_time_s: 10\ncounts,channel\n7,3\n5,0\n2,1\n"))
    np.testing.assert_array_equal(sp.counts, [5, 2, 0, 7])  # sorted by channel, the gap (2) kept as zero
    with pytest.raises(sio.SpectrumFileError, match=r"line 5 channel.*2000000000"):
        sio.read_spectra(_csv(tmp_path, "# live_time_s: 10\nchannel,counts\n0,5\n1,3\n2000000000,4\n"))
    with pytest.raises(sio.SpectrumFileError, match=r"line 4 channel.*already given on line 3"):
        sio.read_spectra(_csv(tmp_path, "# live_time_s: 10\nchannel,counts\n0,5\n0,3\n"))


def test_csv_channel_column_on_a_real_spectrum(tmp_path):
    """Cs137_b.xml's 1024 real channels as channel,counts rows in a shuffled order with 37 channels left out: read
    back channel for channel, the missing ones as zeros (before the channel column was honoured, the rows were
    read in file order and the gaps collapsed)."""
    sp = sio.read_spectrum(DATA / "Cs137_b.xml")
    rng = np.random.default_rng(32)
    keep = np.sort(rng.choice(1024, 1024 - 37, replace=False))
    keep = np.union1d(keep, [1023])  # the last channel kept: the spectrum keeps its length
    rows = rng.permutation(keep)
    text = "# live_time_s: 300\ncounts,channel\n" + "".join(f"{int(sp.counts[i])},{i}\n" for i in rows)
    got = sio.read_spectrum(_csv(tmp_path, text))
    want = np.zeros(1024)
    want[keep] = sp.counts[keep]
    np.testing.assert_array_equal(got.counts, want)
    assert got.counts.sum() < sp.counts.sum()  # a gap holding counts was left out, not shifted


def test_csv_live_time_keys_and_command_line(tmp_path):
    body = "channel,energy_keV,counts\n0,10,1\n1,12,2\n2,14,3\n"
    for head, live, real in (("# MeasurementTime,532\n", 532, None), ("LiveTime,300\nRealTime,310\n", 300, 310),
                             ("# Live Time (s): 12.5\n", 12.5, None), ("# real_time_s: 40\n", 40, None)):
        sp = sio.read_spectrum(_csv(tmp_path, head + body))
        assert (sp.livetime, sp.realtime) == (live, real), head
        assert sp.calibration == pytest.approx((10.0, 2.0, 0.0), abs=1e-9)  # fitted through the energy column
    with pytest.raises(sio.SpectrumFileError, match="--live-time"):
        sio.read_spectra(_csv(tmp_path, body))
    assert sio.read_spectrum(_csv(tmp_path, body), live_time_s=60).livetime == 60
    # the file's own live time is never replaced; a stated real time is kept beside --live-time
    assert sio.read_spectrum(_csv(tmp_path, "# live_time_s: 40\n" + body), live_time_s=60).livetime == 40
    sp = sio.read_spectrum(_csv(tmp_path, "# real_time_s: 70\n" + body), live_time_s=60)
    assert (sp.livetime, sp.realtime) == (60, 70)
    sp = sio.read_spectrum(_csv(tmp_path, "# live_time_s: 5\nEnergy (keV);Counts\n30;1\n10;4\n20;2\n"))
    np.testing.assert_array_equal(sp.counts, [4, 2, 1])  # energy rows sorted, ';' delimited
    np.testing.assert_allclose(sp.edges_keV(), [10, 20, 30, 40])


# ------------------------------------------------------------------------------------------------ bad input


@pytest.mark.parametrize("text, field", [
    ("# live_time_s: 1e29\n1\n2\n", "live time"),
    ("# live_time_s: 0\n1\n2\n", "live time"),
    ("# live_time_s: 10\n# real_time_s: 5\n1\n2\n", "exceeds the real time"),
    ("# live_time_s: 10\n1\n1e300\n", "channel 1"),
    ("# live_time_s: 10\n1\n1e13\n", "channel 1"),
])
def test_absurd_counts_and_times_refused_naming_the_field(tmp_path, text, field):
    with pytest.raises(sio.SpectrumFileError, match=field):
        sio.read_spectra(_csv(tmp_path, text))


def test_absurd_values_in_xml_refused(tmp_path):
    text = (DATA / "Cs137_b.xml").read_text()
    p = tmp_path / "x.xml"
    p.write_text(text.replace("<MeasurementTime>300</MeasurementTime>", "<MeasurementTime>1e29</MeasurementTime>"))
    with pytest.raises(sio.SpectrumFileError, match="EnergySpectrum.*live time"):
        sio.read_spectra(p)
    p.write_text(text.replace("<DataPoint>0</DataPoint>", "<DataPoint>1e300</DataPoint>", 1))
    with pytest.raises(sio.SpectrumFileError, match="channel"):
        sio.read_spectra(p)


def test_file_size_limit(tmp_path):
    p = tmp_path / "big.csv"
    p.write_bytes(b"# live_time_s: 1\n" + b"1\n" * 60_000)
    with pytest.raises(sio.SpectrumFileError, match="over the 0 MB limit"):
        sio.read_spectra(p, max_bytes=100_000)
    assert sio.read_spectrum(p, max_bytes=200_000).n_channels == 60_000
    big = tmp_path / "big.rcspg"
    big.write_bytes(K40.read_bytes())
    with pytest.raises(sio.SpectrumFileError, match="limit"):
        sio.read_spectra(big, max_bytes=1_000_000)


def test_calibrate_and_show_refuse_bad_real_files_naming_the_field(tmp_path, capsys):
    """The issue's bad inputs on real files, through the commands: a channel of 1e300 counts or a live time of
    1e29 s in Cs137_b.xml (they used to run 200 s and write NaN), and a 500 MB file (a sparse one: it used to take
    6-7 GB and end in a MemoryError). Each is refused in one line naming the file and the field, before any fit,
    with no detector file written and no traceback."""
    from radseek_cli.main import main

    text = (DATA / "Cs137_b.xml").read_text()
    huge = tmp_path / "huge.xml"
    with open(huge, "wb") as f:
        f.write(text.encode()[:200])
        f.truncate(500 * 10**6)
    cases = ((text.replace("<DataPoint>0</DataPoint>", "<DataPoint>1e300</DataPoint>", 1), "channel"),
             (text.replace("<MeasurementTime>300</MeasurementTime>", "<MeasurementTime>1e29</MeasurementTime>"),
              "live time"), (None, "500.0 MB, over the 64 MB limit"))
    out = tmp_path / "det.json"
    for k, (body, field) in enumerate(cases):
        path = huge if body is None else tmp_path / f"bad{k}.xml"
        if body is not None:
            path.write_text(body)
        if body is None:  # the last case: the commands' modules are imported by then, only the file is traced
            tracemalloc.start()
        try:
            rcs = (main(["calibrate", str(path), "--nuclide", "Cs-137", "--out", str(out), "--json"]),
                   main(["calibrate", f"{path}=Cs-137", f"{DATA / 'Eu152_b.xml'}=Eu-152", "--out", str(out)]),
                   flight_cli.main(["show", str(path), "--json"]))
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        cap = capsys.readouterr()
        assert rcs == (2, 2, 2) and cap.out == "", (field, rcs, cap.out)
        lines = cap.err.strip().splitlines()
        assert len(lines) == 3 and all(str(path) in ln and field in ln for ln in lines), cap.err
        assert "Traceback" not in cap.err and not out.exists()
    assert peak < 10e6, peak  # the 500 MB file is never read


# ------------------------------------------------------------------------------------------------ commands


def _run(*args):
    return subprocess.run([sys.executable, "-m", "radseek_cli", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO, timeout=300)


@pytest.mark.io
def test_show_json_is_strict_and_complete():
    r = _run("spectra", "show", WALK, "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout, parse_constant=lambda c: pytest.fail(f"{c} in --json output"))
    kinds = [s["kind"] for s in d["spectra"]]
    assert kinds == ["foreground", "accumulated"]
    for s in d["spectra"]:
        assert {"live_time_s", "real_time_s", "total_counts", "channels", "calibration_keV", "start_time", "serial",
                "kind"} <= set(s)
    assert d["rows"]["count"] == 80 and d["gnss_fixes"]["count"] == 406
    assert d["gnss_fixes"]["first"]["time"] == "2025-03-28T07:14:50.000Z"
    r = _run("spectra", "show", K40)
    assert r.returncode == 0 and "rows: 690" in r.stdout and "accumulated" in r.stdout, r.stdout + r.stderr


@pytest.mark.io
def test_show_csv_live_time_from_the_command_line(tmp_path):
    p = _csv(tmp_path, "channel,counts\n1,5\n0,4\n")
    r = _run("spectra", "show", p, "--json")
    assert r.returncode == 2 and "--live-time" in r.stderr
    r = _run("spectra", "show", p, "--json", "--live-time", "30")
    assert r.returncode == 0, r.stderr
    (s,) = json.loads(r.stdout)["spectra"]
    assert (s["live_time_s"], s["total_counts"], s["channels"], s["real_time_s"]) == (30, 9, 2, None)


@pytest.mark.io
def test_show_refuses_bad_file_without_traceback(tmp_path):
    p = _csv(tmp_path, "# live_time_s: 10\nchannel,counts\n0,5\n2000000000,4\n")
    r = _run("spectra", "show", p, "--json")
    assert r.returncode == 2 and "Traceback" not in r.stderr and "2000000000" in r.stderr


@pytest.mark.io
def test_import_ndjson_flight_then_localize(tmp_path):
    out = tmp_path / "walk"
    assert flight_cli.main(["import-flight", str(WALK), "--out", str(out)]) == 0
    ds = read_dataset(out)
    f = ds.frames
    assert len(f) == 80 and np.all(np.diff(f.t) > 0) and np.all(f.duration > 4.9) and np.all(f.duration < 5.2)
    # home is the first fix: the frames lie within the track's extent (tens of metres), variance from sep
    assert np.all(np.abs(f.x) < 200) and np.all(np.abs(f.y) < 200)
    assert np.all(f.var_x > 1) and np.all(f.var_x < 400)
    assert f.counts.shape == (80, 32) and f.counts.sum() > 0
    r = _run("localize", out)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "source 1" in r.stdout
    # the same log with a pose file, or into a non-empty directory, is refused plainly
    assert flight_cli.main(["import-flight", str(WALK), "--out", str(out)]) == 2


def test_import_refuses_a_track_longer_than_a_dataset_holds(tmp_path, capsys):
    """radiacode-tools' whole log (6,913 lines) is a 2.9 km drive: import-flight wrote a scenario.json that radseek's
    own reader refused (bounds over 2000 m), so localize failed on it. The walk's last fixes moved 3 km east: the
    import is refused in one line naming the extent, and nothing is written; the dataset writer refuses such bounds
    too."""
    from radseek.dataset import DatasetError
    from radseek_io.dataset import write_dataset

    lines = WALK.read_text().splitlines()
    fixes = [i for i, ln in enumerate(lines) if '"gnss": true' in ln]
    for i in fixes[-50:]:
        r = json.loads(lines[i])
        lines[i] = json.dumps(dict(r, lon=r["lon"] + 0.034))  # 3.0 km east at 37.6 deg N
    far = tmp_path / "far.ndjson"
    far.write_text("\n".join(lines) + "\n")
    out = tmp_path / "far"
    assert flight_cli.main(["import-flight", str(far), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(far) in err and "over the 2000 m per axis" in err, err
    assert float(err.split("track spans ")[1].split(" x ")[0]) > 2900
    assert not out.exists()
    ds = read_dataset(_import(tmp_path))
    ds.scenario.bounds_max[0] = ds.scenario.bounds_min[0] + 2500.0
    with pytest.raises(DatasetError, match="spans 2500 x"):
        write_dataset(tmp_path / "wide", ds.frames, ds.scenario)
    assert not (tmp_path / "wide").exists()


def _import(tmp_path) -> Path:
    out = tmp_path / "walk"
    assert flight_cli.main(["import-flight", str(WALK), "--out", str(out)]) == 0
    return out


def test_geodetic_to_enu_known_offsets():
    home = (37.0, -122.0, 10.0)
    e = flight_cli.geodetic_to_enu([37.0, 37.001, 37.0], [-122.0, -122.0, -121.999], [10.0, 10.0, 15.0], home)
    assert e[0] == pytest.approx([0, 0, 0], abs=1e-6)
    assert e[1][1] == pytest.approx(110.99, rel=2e-3) and abs(e[1][0]) < 1e-3  # 0.001 deg of latitude north
    assert e[2][0] == pytest.approx(88.9, rel=3e-3) and e[2][2] == pytest.approx(5.0, abs=0.01)
    assert math.isfinite(float(e.sum()))
