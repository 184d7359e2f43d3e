"""``radseek spectra``: flights to and from other tools' formats.

    radseek spectra export-n42 DATASET_DIR --out flight.n42
        one N42.42-2011 RadMeasurement per dwell (frames of the dwell summed, live time = their durations,
        the 32 channels written with their energy boundaries), for InterSpec, becquerel or SpecUtils;
        ``--transit`` adds the transit frames as one more measurement.

    radseek spectra import-flight SPECTROGRAM.csv POSES.csv --out DATASET_DIR [--scene S] [--nuclide N]
        a real flight recorded by another tool, into the dataset format (frames.csv, scenario.json):
        SPECTROGRAM.csv: one row per sample, ``time_s,duration_s,c0,c1,...`` (native channels; ``duration_s``
        may be left out, then the gap to the next sample), with a ``# calibration: c0 c1 c2`` comment line
        (lower channel edge E(i) = c0 + c1 i + c2 i^2 keV, as N42); POSES.csv: ``time_s,x,y,z,yaw`` with optional
        ``var_x,var_y,var_z,dwell`` columns (metres, radians, a dwell index or -1). Each sample's native
        channels are assigned whole to the 32 channels of the scene's comparator edges by their centre energy
        (counts stay integers); the pose is interpolated at the sample's mid-time; samples outside the pose
        track are dropped (counted in the message).

    radseek spectra import-flight LOG.ndjson --out DATASET_DIR [--home LAT,LON,ALT] [--serial SN]
        a radiacode-tools (rcmultispg) log with GNSS fixes: cumulative spectra differenced into frames, GNSS to the
        local ENU frame, position variance from the fixes' quality (:func:`import_ndjson_flight`).

    radseek spectra show FILE [--json] [--live-time S]
        what the readers make of any spectrum file (:mod:`spectra.show`).
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path

import numpy as np

from radseek.dataset import Frames, Scenario
from radseek_io.dataset import MAX_EXTENT_M, read_dataset, write_dataset
from radseek_io.spectrum_io import Spectrum, SpectrumFileError, read_commented_csv, write_n42

EPOCH = dt.datetime(1970, 1, 1, tzinfo=dt.UTC)


def dwell_spectra(frames: Frames, edges_keV: np.ndarray, transit: bool = False) -> list[Spectrum]:
    """One 32-channel spectrum per dwell (in order of first appearance), optionally one for all transit frames."""
    labels = [int(d) for d in dict.fromkeys(int(v) for v in frames.dwell) if d >= 0 or transit]
    out = []
    for d in labels:
        sel = frames.dwell == d
        counts = np.asarray(frames.counts[sel], dtype=float).sum(axis=0)
        live = float(frames.duration[sel].sum())
        if live <= 0:
            continue
        t0 = float(frames.t[sel].min() - frames.duration[sel][0] / 2)
        x, y, z = (float(np.mean(a[sel])) for a in (frames.x, frames.y, frames.z))
        title = (f"dwell {d}" if d >= 0 else "transit") + f" at x={x:.2f} y={y:.2f} z={z:.2f} m, "
        title += f"{int(sel.sum())} frames"
        start = (EPOCH + dt.timedelta(seconds=max(t0, 0.0))).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
        out.append(Spectrum(counts, live, live, bin_edges_kev=np.asarray(edges_keV, dtype=float), start_time=start,
                            title=title, kind="foreground", source=f"dwell {d}",
                            meta={"dwell": d, "x": x, "y": y, "z": z}))
    return out


def export_n42(dataset: str | Path, out: str | Path, transit: bool = False) -> Path:
    ds = read_dataset(dataset)
    spectra = dwell_spectra(ds.frames, ds.scenario.channel_edges_keV, transit)
    if not spectra:
        raise SpectrumFileError(f"{dataset}: no dwell frames (dwell >= 0) to export")
    return write_n42(out, spectra, instrument="radseek 32-channel comparator board")


def _read_table(path: Path) -> tuple[dict[str, str], list[str], np.ndarray]:
    meta, rows = read_commented_csv(path.read_text())
    header = [c.strip().lower() for c in rows.pop(0)] if rows else None
    if header is None or not rows:
        raise SpectrumFileError(f"{path}: needs a header row and at least one data row")
    try:
        arr = np.array([[float(c) for c in r] for r in rows])
    except ValueError as exc:
        raise SpectrumFileError(f"{path}: non-numeric value ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != len(header):
        raise SpectrumFileError(f"{path}: every row needs {len(header)} columns")
    if not np.all(np.isfinite(arr)):
        raise SpectrumFileError(f"{path}: values must be finite")
    return meta, header, arr


def board_channel_map(cal, n_native: int, edges_keV: np.ndarray) -> np.ndarray:
    """The board channel (0..31) of each native channel by its centre energy; -1 below the first edge (the board's
    threshold); the last channel is open above (overflow)."""
    i = np.arange(n_native + 1, dtype=float)
    bounds = sum(c * i**k for k, c in enumerate(cal))
    centre = 0.5 * (bounds[1:] + bounds[:-1])
    edges = np.asarray(edges_keV, dtype=float)
    ch = np.searchsorted(edges, centre, side="right") - 1
    return np.where(centre >= edges[-1], len(edges) - 2, ch)


def to_board(counts_native: np.ndarray, ch: np.ndarray, n_board: int) -> np.ndarray:
    """Native counts (..., n_native) summed into the board channels of ``ch`` (counts stay integers)."""
    c = np.atleast_2d(counts_native)
    out = np.zeros((c.shape[0], n_board), dtype=np.int64)
    for k in range(n_board):
        out[:, k] = np.rint(c[:, ch == k].sum(axis=1)).astype(np.int64)
    return out


WGS84_A = 6378137.0
WGS84_F = 1 / 298.257223563


def geodetic_to_enu(lat, lon, alt, home: tuple[float, float, float]) -> np.ndarray:
    """(n, 3) east, north, up (m) of WGS84 points relative to ``home`` (lat, lon deg, alt m): geodetic to ECEF,
    then rotated into the home's local tangent plane."""
    e2 = WGS84_F * (2 - WGS84_F)

    def ecef(la, lo, h):
        la, lo = np.radians(la), np.radians(lo)
        n = WGS84_A / np.sqrt(1 - e2 * np.sin(la) ** 2)
        return np.stack([(n + h) * np.cos(la) * np.cos(lo), (n + h) * np.cos(la) * np.sin(lo),
                         (n * (1 - e2) + h) * np.sin(la)], axis=-1)

    p = ecef(np.asarray(lat, float), np.asarray(lon, float), np.asarray(alt, float))
    p0 = ecef(np.float64(home[0]), np.float64(home[1]), np.float64(home[2]))
    la0, lo0 = np.radians(home[0]), np.radians(home[1])
    r = np.array([[-np.sin(lo0), np.cos(lo0), 0.0],
                  [-np.sin(la0) * np.cos(lo0), -np.sin(la0) * np.sin(lo0), np.cos(la0)],
                  [np.cos(la0) * np.cos(lo0), np.cos(la0) * np.sin(lo0), np.sin(la0)]])
    return (p - p0) @ r.T


#: a frame whose mid-time is farther than this from every GNSS fix gets no position and is dropped
MAX_FIX_GAP_S = 10.0


def import_ndjson_flight(log_path: str | Path, out: str | Path, edges_keV: np.ndarray, nuclide: str = "Cs-137",
                         background_cps: float | None = None, source_z: float | None = None,
                         home: tuple[float, float, float] | None = None, serial: str | None = None,
                         max_bytes: int | None = None) -> tuple[Path, dict]:
    """A radiacode-tools NDJSON log (:mod:`radseek_io.spectrum_io.ndjson`) as a dataset: one frame per pair of
    consecutive cumulative spectra (their difference, its own duration), rebinned to the board's channels; the
    position is the GNSS track in the local ENU frame (home = the first fix, or ``home``) interpolated at the
    frame's mid-time, its variance from the fixes' stated quality; yaw from the GNSS course (the detector axis
    assumed along the direction of travel; 0 without a course). ``background_cps`` defaults to the median frame
    rate, ``source_z`` to 1 m below the median detector height (a hand-carried detector). Returns the dataset
    path and a summary (frames kept, dropped and why)."""
    from radseek_io.spectrum_io.ndjson import scan

    edges = np.asarray(edges_keV, dtype=float)
    maps: dict[tuple, np.ndarray] = {}
    rows: list[tuple[float, float, np.ndarray]] = []

    def on_frame(fr) -> None:
        key = (fr.calibration, len(fr.counts))
        if key not in maps:
            maps[key] = board_channel_map(fr.calibration, len(fr.counts), edges)
        rows.append((fr.start_s, fr.end_s, to_board(fr.counts, maps[key], len(edges) - 1)[0]))

    log = scan(log_path, serial=serial, on_frame=on_frame, max_bytes=max_bytes)
    p = Path(log_path)
    if not rows:
        raise SpectrumFileError(f"{p}: no frame: {log.spectrum_records} spectrum records, {log.resets} device resets, "
                                f"{log.timing_breaks} timing breaks")
    fixes = log.gnss
    if not fixes:
        raise SpectrumFileError(f"{p}: no GNSS fix in the log ({log.gnss_without_fix} records without a fix): give a "
                                "pose track CSV instead")
    ft = np.array([f.t for f in fixes])
    keep_fix = np.r_[True, np.diff(ft) > 0]  # duplicate fix times: the first is kept
    fixes = [f for f, k in zip(fixes, keep_fix, strict=True) if k]
    ft = ft[keep_fix]
    alts = np.array([np.nan if f.alt is None else f.alt for f in fixes])
    if np.all(np.isnan(alts)):
        alts[:] = 0.0
    else:
        good = ~np.isnan(alts)
        alts = np.interp(ft, ft[good], alts[good])
    home = home if home is not None else (fixes[0].lat, fixes[0].lon, float(alts[0]))
    enu = geodetic_to_enu([f.lat for f in fixes], [f.lon for f in fixes], alts, home)
    start = np.array([r[0] for r in rows])
    end = np.array([r[1] for r in rows])
    mid = 0.5 * (start + end)
    near = np.abs(ft[np.clip(np.searchsorted(ft, mid), 0, len(ft) - 1)] - mid)
    near = np.minimum(near, np.abs(ft[np.clip(np.searchsorted(ft, mid) - 1, 0, len(ft) - 1)] - mid))
    keep = (mid >= ft[0] - MAX_FIX_GAP_S) & (mid <= ft[-1] + MAX_FIX_GAP_S) & (near <= MAX_FIX_GAP_S)
    if not keep.any():
        raise SpectrumFileError(f"{p}: no frame lies within {MAX_FIX_GAP_S:g} s of a GNSS fix (frames "
                                f"{start[0]:.0f}..{end[-1]:.0f}, fixes {ft[0]:.0f}..{ft[-1]:.0f} unix s)")
    m = mid[keep]
    x, y, z = (np.interp(m, ft, enu[:, k]) for k in range(3))
    var_h = np.interp(m, ft, [f.sigma_h**2 for f in fixes])
    var_v = np.interp(m, ft, [f.sigma_v**2 for f in fixes])
    idx = np.clip(np.searchsorted(ft, m), 0, len(ft) - 1)
    yaw = np.array([0.0 if fixes[i].track_deg is None else np.radians(90.0 - fixes[i].track_deg) for i in idx])
    yaw = np.angle(np.exp(1j * yaw))
    counts = np.stack([r[2] for r, k in zip(rows, keep, strict=True) if k])
    dur = (end - start)[keep]
    t0 = start[keep][0]
    frames = Frames(t=end[keep] - t0, duration=dur, x=x, y=y, z=z, yaw=yaw, var_x=var_h, var_y=var_h.copy(),
                    var_z=var_v, dwell=np.full(len(m), -1), counts=counts)
    rate = counts.sum(axis=1) / dur
    bg = float(np.median(rate)) if background_cps is None else float(background_cps)
    sz = float(np.median(z) - 1.0) if source_z is None else float(source_z)
    lo = np.array([x.min(), y.min(), min(z.min(), sz)]) - 5.0
    hi = np.array([x.max(), y.max(), z.max()]) + 5.0
    if np.any(hi - lo > MAX_EXTENT_M):
        raise SpectrumFileError(f"{p}: the GNSS track spans {' x '.join(f'{v:.0f}' for v in hi - lo)} m (east, north, "
                                f"up), over the {MAX_EXTENT_M:g} m per axis a dataset holds: import the part of the "
                                "log that covers one search area")
    scenario = Scenario(channel_edges_keV=edges, background_cps=bg, source_z=sz, bounds_min=lo, bounds_max=hi,
                        nuclide=nuclide)
    summary = {"frames": int(keep.sum()), "dropped_no_fix": int((~keep).sum()), "device_resets": log.resets,
               "timing_breaks": log.timing_breaks, "recalibrations": log.recalibrations,
               "out_of_order_skipped": log.out_of_order, "gnss_fixes": len(fixes), "home": list(home),
               "background_cps": bg, "source_z": sz, "serial": log.serial, "notes": log.notes}
    return write_dataset(out, frames, scenario), summary


def import_flight(spectrogram: str | Path, poses: str | Path, out: str | Path, edges_keV: np.ndarray,
                  nuclide: str = "Cs-137", background_cps: float = 0.0, source_z: float | None = None
                  ) -> tuple[Path, int]:
    sp_path, pose_path = Path(spectrogram), Path(poses)
    meta, head, arr = _read_table(sp_path)
    if "time_s" not in head:
        raise SpectrumFileError(f"{sp_path}: column 'time_s' missing")
    if "calibration" not in meta:
        raise SpectrumFileError(f"{sp_path}: '# calibration: c0 c1 c2' comment line missing")
    cal = [float(v) for v in meta["calibration"].replace(",", " ").split()]
    t = arr[:, head.index("time_s")]
    if np.any(np.diff(t) <= 0):
        raise SpectrumFileError(f"{sp_path}: column 'time_s' must increase")
    chan_cols = [i for i, h in enumerate(head) if h not in ("time_s", "duration_s")]
    counts_native = arr[:, chan_cols]
    if np.any(counts_native < 0) or np.any(counts_native != np.round(counts_native)):
        raise SpectrumFileError(f"{sp_path}: channel counts must be integers >= 0")
    if "duration_s" in head:
        dur = arr[:, head.index("duration_s")]
    else:
        gaps = np.diff(t)
        dur = np.r_[gaps, gaps[-1] if len(gaps) else 1.0]
    if np.any(dur <= 0):
        raise SpectrumFileError(f"{sp_path}: sample durations must be > 0")
    edges = np.asarray(edges_keV, dtype=float)
    counts = to_board(counts_native, board_channel_map(cal, counts_native.shape[1], edges), len(edges) - 1)
    pmeta, phead, parr = _read_table(pose_path)
    for c in ("time_s", "x", "y", "z", "yaw"):
        if c not in phead:
            raise SpectrumFileError(f"{pose_path}: column {c!r} missing")
    pt = parr[:, phead.index("time_s")]
    if np.any(np.diff(pt) <= 0):
        raise SpectrumFileError(f"{pose_path}: column 'time_s' must increase")
    mid = t + dur / 2
    keep = (mid >= pt[0]) & (mid <= pt[-1])
    if not keep.any():
        raise SpectrumFileError(f"{sp_path}: no sample lies within the pose track's time span "
                                f"{pt[0]:g}..{pt[-1]:g} s")

    def col(name: str, default: float) -> np.ndarray:
        if name in phead:
            return np.interp(mid[keep], pt, parr[:, phead.index(name)])
        return np.full(int(keep.sum()), default)

    yaw_track = np.unwrap(parr[:, phead.index("yaw")])
    dwell = (np.round(np.interp(mid[keep], pt, parr[:, phead.index("dwell")])).astype(int) if "dwell" in phead
             else np.full(int(keep.sum()), -1))
    frames = Frames(t=mid[keep], duration=dur[keep], x=col("x", 0), y=col("y", 0), z=col("z", 0),
                    yaw=np.angle(np.exp(1j * np.interp(mid[keep], pt, yaw_track))),
                    var_x=col("var_x", 0.0), var_y=col("var_y", 0.0), var_z=col("var_z", 0.0), dwell=dwell,
                    counts=counts[keep])
    lo = np.array([frames.x.min(), frames.y.min(), frames.z.min()]) - 1.0
    hi = np.array([frames.x.max(), frames.y.max(), frames.z.max()]) + 1.0
    scenario = Scenario(channel_edges_keV=edges, background_cps=float(background_cps),
                        source_z=float(source_z if source_z is not None else 0.0),
                        bounds_min=np.maximum(lo, [lo[0], lo[1], 0.0]),
                        bounds_max=hi, nuclide=nuclide)
    return write_dataset(out, frames, scenario), int((~keep).sum())


def _home(text: str) -> tuple[float, float, float]:
    try:
        v = [float(t) for t in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--home expects lat,lon,alt, got {text!r}") from None
    if len(v) != 3 or not (-90 <= v[0] <= 90 and -180 <= v[1] <= 180 and all(np.isfinite(v))):
        raise argparse.ArgumentTypeError(f"--home expects lat,lon,alt (degrees, degrees, metres), got {text!r}")
    return v[0], v[1], v[2]


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return v


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="radseek spectra", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export-n42", help="write each dwell's spectrum of a dataset as N42")
    e.add_argument("dataset")
    e.add_argument("--out", required=True)
    e.add_argument("--transit", action="store_true", help="add the transit frames as one more measurement")
    sh = sub.add_parser("show", help="print what the readers make of a spectrum file (any format read)")
    sh.add_argument("file")
    sh.add_argument("--json", action="store_true", help="strict JSON (null for a missing or non-finite value)")
    sh.add_argument("--live-time", type=_positive, help="live time (s) of a CSV that states none")
    sh.add_argument("--max-mb", type=_positive, help="raise the file size limit (default 64 MB)")
    im = sub.add_parser("import-flight", help="spectrogram CSV + pose track CSV, or a radiacode-tools NDJSON log "
                                              "with GNSS fixes -> dataset directory")
    im.add_argument("spectrogram", help="spectrogram CSV, or an .ndjson log (spectra + GNSS fixes)")
    im.add_argument("poses", nargs="?", help="pose track CSV (not with an .ndjson log)")
    im.add_argument("--out", required=True)
    im.add_argument("--scene", help="scene whose comparator edges define the 32 channels (default scene)")
    im.add_argument("--nuclide", default="Cs-137")
    im.add_argument("--background-cps", type=float, default=None,
                    help="operator's background estimate (default: 0 for CSV, the median frame rate for NDJSON)")
    im.add_argument("--source-z", type=float, default=None)
    im.add_argument("--home", type=_home, help="NDJSON: local frame origin lat,lon,alt (default: the first fix)")
    im.add_argument("--serial", help="NDJSON: the device to import (default: the first one in the log)")
    im.add_argument("--max-mb", type=_positive, help="raise the file size limit (default 64 MB)")
    a = ap.parse_args(argv)
    try:
        if a.cmd == "export-n42":
            p = export_n42(a.dataset, a.out, a.transit)
            print(f"wrote {p}")
        elif a.cmd == "show":
            from spectra.show import describe, dumps, human

            d = describe(a.file, a.live_time, int(a.max_mb * 1e6) if a.max_mb else None)
            print(dumps(d) if a.json else human(d))
        else:
            from detector_fw_sim.scene import load_scene
            from radseek_io.spectrum_io import format_of

            edges = load_scene(a.scene).channel_edges_keV
            max_bytes = int(a.max_mb * 1e6) if a.max_mb else None
            if format_of(a.spectrogram, None, max_bytes) == "ndjson":
                if a.poses:
                    raise SpectrumFileError(f"{a.poses}: an NDJSON log brings its own GNSS track; give no pose file")
                if Path(a.out).exists() and any(Path(a.out).iterdir()):
                    raise SpectrumFileError(f"{a.out}: exists and is not empty; choose a new --out")
                p, summary = import_ndjson_flight(a.spectrogram, a.out, edges, a.nuclide, a.background_cps,
                                                  a.source_z, a.home, a.serial, max_bytes)
                bg = " (the median frame rate)" if a.background_cps is None else ""
                print(f"wrote {p}: {summary['frames']} frames from {summary['serial'] or 'the device'}, "
                      f"{summary['gnss_fixes']} GNSS fixes, home {summary['home'][0]:.6f},{summary['home'][1]:.6f},"
                      f"{summary['home'][2]:.1f}; background {summary['background_cps']:.3g} cps{bg}")
                skipped = {k: summary[k] for k in ("dropped_no_fix", "device_resets", "timing_breaks",
                                                   "recalibrations", "out_of_order_skipped") if summary[k]}
                if skipped:
                    print("  no frame across: " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in skipped.items()))
                for n in summary["notes"]:
                    print(f"  note: {n}")
            else:
                if not a.poses:
                    raise SpectrumFileError(f"{a.spectrogram}: a spectrogram CSV needs a pose track CSV")
                p, dropped = import_flight(a.spectrogram, a.poses, a.out, edges, a.nuclide,
                                           a.background_cps or 0.0, a.source_z)
                print(f"wrote {p}" + (f" ({dropped} samples outside the pose track dropped)" if dropped else ""))
    except (SpectrumFileError, ValueError, FileNotFoundError) as exc:
        print(f"radseek spectra: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
