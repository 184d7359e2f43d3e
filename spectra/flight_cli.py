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
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
from pathlib import Path

import numpy as np

from radseek.dataset import Frames, Scenario, read_dataset, write_dataset
from radseek.spectrum_files import Spectrum, SpectrumFileError, read_commented_csv, write_n42

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
        out.append(Spectrum(counts, live, live, boundaries_keV=np.asarray(edges_keV, dtype=float), start_time=start,
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
    i = np.arange(counts_native.shape[1] + 1, dtype=float)
    bounds = sum(c * i**k for k, c in enumerate(cal))
    centre = 0.5 * (bounds[1:] + bounds[:-1])
    edges = np.asarray(edges_keV, dtype=float)
    ch = np.searchsorted(edges, centre, side="right") - 1  # channel of each native channel; < 0: below threshold
    ch = np.where(centre >= edges[-1], len(edges) - 2, ch)  # the overflow channel is open above
    counts = np.zeros((len(t), len(edges) - 1), dtype=np.int64)
    for k in range(len(edges) - 1):
        counts[:, k] = counts_native[:, ch == k].sum(axis=1).astype(np.int64)
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="radseek spectra", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export-n42", help="write each dwell's spectrum of a dataset as N42")
    e.add_argument("dataset")
    e.add_argument("--out", required=True)
    e.add_argument("--transit", action="store_true", help="add the transit frames as one more measurement")
    im = sub.add_parser("import-flight", help="spectrogram CSV + pose track CSV -> dataset directory")
    im.add_argument("spectrogram")
    im.add_argument("poses")
    im.add_argument("--out", required=True)
    im.add_argument("--scene", help="scene whose comparator edges define the 32 channels (default scene)")
    im.add_argument("--nuclide", default="Cs-137")
    im.add_argument("--background-cps", type=float, default=0.0)
    im.add_argument("--source-z", type=float, default=None)
    a = ap.parse_args(argv)
    try:
        if a.cmd == "export-n42":
            p = export_n42(a.dataset, a.out, a.transit)
            print(f"wrote {p}")
        else:
            from detector_fw_sim.scene import load_scene

            edges = load_scene(a.scene).channel_edges_keV
            p, dropped = import_flight(a.spectrogram, a.poses, a.out, edges, a.nuclide, a.background_cps, a.source_z)
            print(f"wrote {p}" + (f" ({dropped} samples outside the pose track dropped)" if dropped else ""))
    except (SpectrumFileError, ValueError, FileNotFoundError) as exc:
        print(f"radseek spectra: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
