"""The run report: what a person looks at after a mission (``report.png``) and ``summary.json``.

One estimate everywhere: the report and the summary show the estimate the mission flew with (the last
record of ``estimator.inflight``, walls included when it used them, as in ``mission_summary.json``), not
a post-flight refit; only a flight that never had an in-flight estimate gets one, from the same policy on
the whole recording (``estimate_source`` says which). The final record carries the drift-aware bound
``bound_m`` and the 95 % ellipse (``InflightEstimator.finalize``; computed here for a flight that ended
before the mission could add them).

Panels: the map (walls, flown path, dwell points scaled by rate, the estimate against the truth, and an
inset zoomed on the estimate with its 1-sigma and 95 % ellipses); error, 1-sigma and Gaussian entropy
(paper 000 eq. 15) against dwell number, with the stop rule (1-sigma < ``stop_sigma_m``) as the target and
the final bound; the recorded spectrum per dwell (channels with no counts left as gaps); the count rate
over time.

``summary.json`` keys: ``error_m`` (the estimate's horizontal distance from the truth), ``sigma_m``
(1-sigma semi-major axis, m; inf if not trustworthy), ``ellipse_95`` (``a_m``, ``b_m`` semi-axes, m, and
``angle_deg`` of the major axis from east), ``bound_m`` (drift-aware Cramér-Rao bound, rms horizontal, m),
``p_value`` (goodness of fit), ``warnings``, ``estimate`` (the whole record), ``estimate_source``
(``in-flight`` or ``post-flight``), ``stop_sigma_m``, the mission's counts and times, ``truth``, ``stop_reason``
(for people) and ``outcome`` (``radseek.outcome.Outcome``'s value, for programs), ``samples`` (per key the
mission subscribed to: samples taken and dropped, and per publisher what was dropped, ``mission.key_accounts``;
a flood or forgery is also a line of ``warnings``) and ``histogram_queue``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Ellipse, Polygon  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from radseek.dataset import Dataset, DatasetError  # noqa: E402
from radseek.estimate import SourceEstimate  # noqa: E402
from radseek.geometry import semi_major_axis  # noqa: E402
from radseek_io.outdir import atomic_path, atomic_write_json  # noqa: E402
from radseek_io.truth import read_dataset_with_truth  # noqa: E402


def gaussian_entropy(cov: np.ndarray) -> float:
    """Differential entropy of a Gaussian, 0.5 ln((2 pi e)^k det C) (paper 000 eq. 15)."""
    cov = np.atleast_2d(cov)
    sign, logdet = np.linalg.slogdet(cov)
    if sign <= 0:
        return float("nan")
    k = cov.shape[0]
    return float(0.5 * (k * math.log(2 * math.pi * math.e) + logdet))


def _ellipse(ax, mean, cov, n_sigma, **kw) -> None:
    w, v = np.linalg.eigh(cov)
    w = np.clip(w, 0, None)
    angle = math.degrees(math.atan2(v[1, -1], v[0, -1]))
    ax.add_patch(Ellipse(mean, 2 * n_sigma * math.sqrt(w[-1]), 2 * n_sigma * math.sqrt(w[0]), angle=angle,
                         fill=False, **kw))


#: the 95 % ellipse of a 2-D Gaussian in sigmas: sqrt(-2 ln 0.05)
N_SIGMA_95 = math.sqrt(-2 * math.log(0.05))


def _wall_polygon(w) -> np.ndarray:
    s, e = np.array(w.start), np.array(w.end)
    u = (e - s) / max(np.linalg.norm(e - s), 1e-9)
    n = np.array([-u[1], u[0]]) * w.thickness / 2
    return np.array([s + n, e + n, e - n, s - n])


def flown_estimate(ds: Dataset, mission: dict[str, Any]) -> tuple[SourceEstimate, str]:
    """The estimate the mission flew with (its last in-flight record) with ``bound_m`` and ``ellipse_95``,
    and where it came from: ``in-flight``, or ``post-flight`` (the in-flight policy on the whole recording)
    when the mission never had one. ValueError if no estimate can be made."""
    from estimator.inflight import InflightEstimator, flown_bound
    from estimator.mle import pooled

    if not mission.get("estimate"):
        inflight = InflightEstimator(ds.scenario)
        if inflight.update(ds.frames, dwell=int(mission.get("dwell_points", 0))) is None:
            raise ValueError("no in-flight estimate and too few frames for one")
        return SourceEstimate.from_json(inflight.finalize()), "post-flight"
    est = _with_ellipse(SourceEstimate.from_json(mission["estimate"]))
    if est.bound_m is None:  # the flight ended before the mission added it: the frames up to that estimate
        f = ds.frames
        flown = [d for d in dict.fromkeys(f.dwell[f.dwell >= 0].tolist())][: est.dwell or None]
        end = max((int(np.flatnonzero(f.dwell == d).max()) for d in flown), default=len(f) - 1)
        upto = pooled(f.select(np.arange(len(f)) <= end), 10, dwells_only=True)
        est = est.replace(bound_m=flown_bound(ds.scenario, upto, est.to_json()))
    return est, "in-flight"


def _with_ellipse(est: SourceEstimate) -> SourceEstimate:
    """``est`` with its ``ellipse_95`` (as ``InflightEstimator.finalize``: none, infinite, for an estimate that
    is not trustworthy) if it lacks one."""
    from estimator.inflight import ellipse

    if est.ellipse_95 is not None:
        return est
    return est.replace(ellipse_95=ellipse(est.covariance if math.isfinite(est.sigma_m) else np.full((2, 2), np.nan)))


def _map_frame(ax, scenario) -> None:
    """A map's frame: the scenario's bounds with half a metre around, equal scales, east and north labelled."""
    lo, hi = scenario.bounds_min, scenario.bounds_max
    ax.set_xlim(lo[0] - 0.5, hi[0] + 0.5)
    ax.set_ylim(lo[1] - 0.5, hi[1] + 0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")


#: the zoom inset's size (axes fraction) and the corners it may take (lower left, lower right, upper left; the
#: legend holds the upper right)
INSET_SIZE = 0.36
INSET_CORNERS = ((0.02, 0.02), (0.62, 0.02), (0.02, 0.56))


def _emptiest_corner(ax, frames, src: dict[str, float]) -> list[float]:
    """The inset's [x0, y0, w, h] in the corner of the map that hides the fewest dwell points (each worth a
    thousand track frames) and none of the estimate: the inset hid dwells 0 and 1 of five in the lower left."""
    to_axes = ax.transAxes.inverted().transform
    xy = to_axes(ax.transData.transform(np.column_stack([frames.x, frames.y])))
    dw = np.asarray(frames.dwell)
    ks = sorted(set(dw[dw >= 0].tolist()))
    cen = to_axes(ax.transData.transform(np.array([[frames.x[dw == k].mean(), frames.y[dw == k].mean()]
                                                   for k in ks]).reshape(-1, 2)))
    est = to_axes(ax.transData.transform([[src["x"], src["y"]]]))

    def hidden(x0: float, y0: float, pts: np.ndarray) -> int:
        inside = (pts[:, 0] >= x0 - 0.03) & (pts[:, 0] <= x0 + INSET_SIZE + 0.03) & \
                 (pts[:, 1] >= y0 - 0.03) & (pts[:, 1] <= y0 + INSET_SIZE + 0.06)  # its title above it
        return int(inside.sum())

    x0, y0 = min(INSET_CORNERS, key=lambda c: (1000 * hidden(*c, cen) + 10_000 * hidden(*c, est) + hidden(*c, xy)))
    if hidden(x0, y0, cen) or hidden(x0, y0, est):
        # every corner hides a dwell point (a flight over the whole map): make room instead, widening the map to
        # the left by an empty band the inset fits in, so it hides nothing (the flight's points move right)
        lo, hi = ax.get_xlim()
        band = INSET_SIZE + 0.06
        ax.set_xlim(lo - (hi - lo) * band / (1.0 - band), hi)
        return [0.02, 0.02, INSET_SIZE, INSET_SIZE]
    return [x0, y0, INSET_SIZE, INSET_SIZE]


def wrapped_title(text: str, width_in: float, fontsize: float) -> str:
    """``text`` broken into lines that fit ``width_in`` inches at ``fontsize`` points (a run's stop reason runs
    to 200 characters: lattice-wall's ran off the image)."""
    import textwrap

    chars = max(int(0.95 * width_in * 72 / (0.55 * fontsize)), 20)  # an average glyph is ~0.55 em wide
    return "\n".join(textwrap.wrap(text, chars)) or text


def _zoom_inset(ax, ds: Dataset, src: dict[str, float], cov: np.ndarray, est: SourceEstimate, truth) -> None:
    """An inset zoomed on the estimate: its 1-sigma and 95 % ellipses (centimetres, invisible at map
    scale under the marker) and the truth if it is near."""
    w = np.clip(np.linalg.eigvalsh(cov), 0, None) if np.isfinite(cov).all() else np.array([0.0, 0.0])
    a95 = N_SIGMA_95 * math.sqrt(w[-1])
    half = max(1.6 * a95, 0.05)
    if truth:
        d = math.hypot(truth.sources[0].x - src["x"], truth.sources[0].y - src["y"])
        if d < 5 * half:  # show the truth too unless it is far outside the ellipses
            half = max(half, 1.3 * d)
    ins = ax.inset_axes(_emptiest_corner(ax, ds.frames, src))
    for wl in ds.scenario.walls:
        ins.add_patch(Polygon(_wall_polygon(wl), color="0.45", alpha=0.5))
    if a95 > 0:
        _ellipse(ins, (src["x"], src["y"]), cov, 1, color="b", lw=1.5, label="1-sigma")
        _ellipse(ins, (src["x"], src["y"]), cov, N_SIGMA_95, color="b", lw=1.0, ls="--", label="95 %")
    ins.plot(src["x"], src["y"], "b+", ms=8, mew=1.5)
    if truth:
        ins.plot(truth.sources[0].x, truth.sources[0].y, "r*", ms=10)
    ins.set_xlim(src["x"] - half, src["x"] + half)
    ins.set_ylim(src["y"] - half, src["y"] + half)
    ins.set_aspect("equal")
    ins.tick_params(labelsize=6)
    ins.xaxis.set_major_locator(MaxNLocator(3))
    ins.yaxis.set_major_locator(MaxNLocator(3))
    ins.set_facecolor("white")
    sig = est.sigma_m
    ins.set_title(f"zoom: 1-sigma {sig:.3f} m, 95 % (dashed)", fontsize=7)
    ax.indicate_inset_zoom(ins, edgecolor="0.3")


def _tight_layout(fig) -> None:
    """``fig.tight_layout()``, and no layout engine left behind: matplotlib leaves a placeholder engine after it,
    and ``savefig`` then draws the whole figure once more, unseen, before the drawing it saves (0.19 s of the
    report's 1.24 s of CPU). The PNG is the same byte for byte."""
    fig.tight_layout()
    fig.set_layout_engine(None)


def write_report(out: str | Path, wall_time_s: float | None = None, speedup: float | None = None) -> dict[str, Any]:
    from estimator.inflight import excess_warning, gof_warning
    from mission.search import SearchConfig

    out = Path(out)
    ds = read_dataset_with_truth(out / "dataset")
    mission = json.loads((out / "dataset" / "mission_summary.json").read_text())
    est, est_source = flown_estimate(ds, mission)
    src = {"x": est.x, "y": est.y, "z": est.z, "cps_at_1m": est.cps_at_1m}
    cov = est.covariance[:2, :2]
    truth = ds.truth
    err = math.hypot(src["x"] - truth.sources[0].x, src["y"] - truth.sources[0].y) if truth else math.nan
    stop_sigma = float(mission.get("stop_sigma_m", SearchConfig().stop_sigma_m))
    f = ds.frames

    fig, axes = plt.subplots(2, 2, figsize=(13, 10))
    ax = axes[0, 0]
    for w in ds.scenario.walls:
        ax.add_patch(Polygon(_wall_polygon(w), color="0.45", alpha=0.8))
    ax.plot(f.x, f.y, "-", color="0.6", lw=0.8, label="flown path (estimated pose)")
    dwells = sorted(set(f.dwell[f.dwell >= 0].tolist()))
    rates = []
    for k in dwells:
        m = f.dwell == k
        rates.append(f.total_counts[m].sum() / f.duration[m].sum())
        ax.scatter(f.x[m].mean(), f.y[m].mean(), s=20 + 200 * math.sqrt(rates[-1] / max(1.0, max(rates))),
                   color="tab:orange", edgecolor="k", zorder=3)
        ax.annotate(str(k), (f.x[m].mean(), f.y[m].mean()), xytext=(4, 4), textcoords="offset points", fontsize=8)
    walled = " with walls" if "wall_attenuation" in est.effects else ""
    ax.plot(src["x"], src["y"], "b+", ms=14, mew=2,
            label=f"{est_source} estimate{walled} ({src['x']:.2f}, {src['y']:.2f})")
    if truth:
        for s in truth.all_sources():
            ax.plot(s.x, s.y, "r*", ms=14, label="truth" if s is truth.sources[0] else None)
    _map_frame(ax, ds.scenario)
    ax.set_title(f"map: {len(dwells)} dwell points (size ~ rate), error {err:.3f} m")
    ax.legend(fontsize=8, loc="upper right")
    _zoom_inset(ax, ds, src, cov, est, truth)

    ax = axes[0, 1]
    history = [SourceEstimate.from_json(e) for e in mission.get("estimates", [])]
    if history and truth:
        k = [e.dwell for e in history]
        e_err = [math.hypot(e.x - truth.sources[0].x, e.y - truth.sources[0].y) for e in history]
        sig = [e.sigma_m for e in history]
        ax.semilogy(k, e_err, "o-", label="position error (m)")
        ax.semilogy(k, sig, "s--", label="1-sigma semi-major axis (m)")
        # an estimate not trustworthy yet (sigma inf: unconverged or collapsed) shows its ellipse's size hollow
        untrusted = [(kk, semi_major_axis(e.covariance[:2, :2]))
                     for kk, e, s_ in zip(k, history, sig, strict=True) if not math.isfinite(s_)]
        if untrusted:
            ax.semilogy(*zip(*untrusted, strict=True), "s", mfc="none", color="tab:orange",
                        label="its size, not trustworthy yet")
        ax.axhline(stop_sigma, color="0.5", lw=0.8, ls=":", label=f"stop rule: 1-sigma < {stop_sigma:g} m")
        bound = est.bound_m
        if bound is not None and math.isfinite(bound) and bound > 0:
            ax.plot([k[-1]], [bound], "D", color="tab:purple", label=f"drift-aware bound {bound:.3f} m")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("dwell points flown")
        ax.set_ylabel("m")
        ax2 = ax.twinx()
        ent = [gaussian_entropy(np.diag([max(s, 1e-6) ** 2] * 2)) if math.isfinite(s) else math.nan for s in sig]
        ax2.plot(k, ent, "^:", color="tab:green", label="Gaussian entropy (nats)")
        ax2.set_ylabel("entropy (nats, paper 000 eq. 15)")
        ax.legend(fontsize=8, loc="upper right")
        ax2.legend(fontsize=8, loc="lower left")
    ax.set_title("convergence")

    ax = axes[1, 0]
    edges = ds.scenario.channel_edges_keV
    centres = 0.5 * (edges[:-1] + edges[1:])
    for k in dwells:
        m = f.dwell == k
        spec = f.counts[m].sum(0) / f.duration[m].sum() / np.diff(edges)
        # a channel with no counts has no rate density to draw on a log axis: leave a gap, not a floor
        ax.semilogy(centres, np.where(spec > 0, spec, np.nan), drawstyle="steps-mid", lw=0.8, label=f"dwell {k}")
    ax.set_xlabel("energy (keV, comparator channel centres)")
    ax.set_ylabel("rate density (cps/keV)")
    ax.set_title("spectra per dwell point")
    if len(dwells) <= 10:
        ax.legend(fontsize=7, ncol=2)

    ax = axes[1, 1]
    ax.plot(f.t, f.total_counts / f.duration, ",", color="0.3")
    for k in dwells:
        m = f.dwell == k
        ax.axvspan(f.t[m].min(), f.t[m].max(), color="tab:orange", alpha=0.2)
    ax.set_yscale("log")
    ax.set_xlabel("sim time (s)")
    ax.set_ylabel("total count rate (cps)")
    ax.set_title("count rate (dwells shaded)")
    fig.suptitle(wrapped_title(f"radseek run: {mission.get('reason', '')}", fig.get_figwidth(), 11), fontsize=11)
    _tight_layout(fig)
    with atomic_path(out / "report.png") as tmp:  # a reader never sees half a PNG
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)

    warning = gof_warning(est.p_value, out / "dataset")
    excess = excess_warning(est.to_json(), ds.scenario.background_cps, out / "dataset")
    samples = mission.get("samples") or {}
    summary = {
        "error_m": err,
        "sigma_m": float(est.sigma_m),
        "ellipse_95": dict(est.ellipse_95 or {}),
        "bound_m": float(est.bound_m if est.bound_m is not None else math.nan),
        "p_value": float(est.p_value),
        "warnings": [w for w in (warning, excess) if w] + dropped_warnings(samples),
        "estimate_source": est_source,
        "estimate": {**est.to_json(), "sigma_xy_m": [float(v) for v in np.sqrt(np.clip(np.diag(cov), 0, None))]},
        "stop_sigma_m": stop_sigma,
        "dwell_points": int(mission["dwell_points"]),
        "search_dwell_points": int(mission.get("search_dwell_points", 0)),
        "mission_time_s": float(mission["mission_time_s"]),
        "flight_time_s": float(mission.get("flight_time_s", math.nan)),
        "truth": truth.to_dict() if truth else None,
        "stop_reason": mission.get("reason"),
        "outcome": mission.get("outcome"),
        "frames_received": mission.get("frames_received"),
        "frames_recorded": mission.get("frames_recorded"),
        "frames_flagged": mission.get("frames_flagged"),
        "samples": samples,
        "histogram_queue": mission.get("histogram_queue"),
        "wall_time_s": wall_time_s,
        "speedup": speedup,
    }
    atomic_write_json(out / "summary.json", summary)  # last, and whole or not at all
    return summary


#: the kinds of dropped sample a summary warns about: another's (or a forged copy's) samples and floods (invalid
#: payloads are ``bad_payloads``, e.g. a board's corrupted frames)
HOSTILE_DROPS = ("flood", "foreign", "sequence")


def dropped_warnings(samples: dict[str, Any], log: str = "logs/mission.log") -> list[str]:
    """One line per key and publisher whose samples the mission dropped as a flood, as another publisher's or
    as a forged sequence (``mission.key_accounts``: ``mission_summary.json``'s ``samples``)."""
    lines = []
    for key, row in samples.items():
        for publisher, dropped in row.get("dropped_from", {}).items():
            kinds = {k: dropped.get(k, 0) for k in HOSTILE_DROPS if dropped.get(k, 0)}
            if kinds:
                what = ", ".join(f"{k} {n}" for k, n in kinds.items())
                lines.append(f"dropped {sum(kinds.values())} samples on {key} from {publisher} ({what}; "
                             f"{row.get('accepted', 0)} taken on the key): see {log}")
    return lines


#: one colour per vehicle of a team (``radseek run --vehicles N``)
VEHICLE_COLOURS = ("tab:blue", "tab:green", "tab:purple", "tab:brown")


def vehicle_track(frames) -> dict[str, Any]:
    """One vehicle's record as the team summary has it: dwell points (distinct dwell indices) and the
    distance flown between them (estimated path length over the transit frames, m)."""
    moving = frames.dwell[1:] < 0
    step = np.linalg.norm(np.diff(frames.positions, axis=0), axis=1) if len(frames) > 1 else np.zeros(0)
    finite = np.isfinite(step)
    return {"dwell_points": len(set(frames.dwell[frames.dwell >= 0].tolist())),
            "distance_m": float(step[moving & finite].sum())}


def _dwells_ended(log: Path) -> int | None:
    """How many dwells a mission ended, from its ``mission_log.jsonl`` (None without one)."""
    try:
        lines = log.read_text().splitlines()
    except OSError:
        return None
    n = 0
    for line in lines:
        try:
            n += json.loads(line).get("event") == "dwell"
        except ValueError:  # a line cut by a kill
            continue
    return n


def write_team_report(out: str | Path, names: list[str], decider: str | None, killed: dict[str, float] | None = None,
                      wall_time_s: float | None = None, speedup: float | None = None) -> dict[str, Any]:
    """The team's report (``radseek run --vehicles N``): every vehicle's path and dwells on one map, the joint
    estimate that ended the search (``decider``'s) against the truth, and ``summary.json`` with ``per_vehicle``
    ({vehicle, dwell_points, distance_m, failed}) beside ``error_m``, ``sigma_m``, ``mission_time_s``."""
    out = Path(out)
    killed = killed or {}
    data, unreadable = {}, {}
    for n in names:
        if (out / "dataset" / n / "frames.csv").exists():
            try:
                data[n] = read_dataset_with_truth(out / "dataset" / n)
            except DatasetError as exc:  # a member that recorded nothing (killed early, flooded) loses no one else's
                unreadable[n] = str(exc)
    if not data:
        raise ValueError(f"no vehicle's dataset could be read ({'; '.join(unreadable.values()) or 'none recorded'})")
    missions = {}
    for n in names:
        try:
            missions[n] = json.loads((out / "dataset" / n / "mission_summary.json").read_text())
        except (OSError, ValueError):
            continue
    mission = missions.get(decider or "", {})
    if not mission.get("estimate"):
        raise ValueError("the team's search ended without an estimate")
    est = _with_ellipse(SourceEstimate.from_json(mission["estimate"]))
    any_ds = next(iter(data.values()))
    truth = any_ds.truth
    err = math.hypot(est.x - truth.sources[0].x, est.y - truth.sources[0].y) if truth else math.nan
    cov = est.covariance[:2, :2]

    fig, ax = plt.subplots(figsize=(9, 8))
    for w in any_ds.scenario.walls:
        ax.add_patch(Polygon(_wall_polygon(w), color="0.45", alpha=0.8))
    per_vehicle = []
    for i, n in enumerate(names):
        colour = VEHICLE_COLOURS[i % len(VEHICLE_COLOURS)]
        row = {"vehicle": n, "dwell_points": 0, "distance_m": 0.0,
               "failed": n in killed or n not in missions or n in unreadable}
        if n in killed:
            row["failed_at_s"] = killed[n]
        if n in unreadable:
            row["error"] = unreadable[n]
        if n in data:
            f = data[n].frames
            row.update(vehicle_track(f))
            ended = _dwells_ended(out / "dataset" / n / "mission_log.jsonl")
            begun = len(set(f.dwell[f.dwell >= 0].tolist()))
            if ended is not None:  # a dwell counts once it ended (a killed mission's last may not have)
                row["dwell_points"] = ended
                row["dwells_not_ended"] = max(begun - ended, 0)  # in frames.csv and drawn hollow, not counted
            state = " (failed)" if row["failed"] else ""
            more = f" (+{row['dwells_not_ended']} begun, not ended: hollow)" if row.get("dwells_not_ended") else ""
            ax.plot(f.x, f.y, "-", color=colour, lw=0.9, alpha=0.8,
                    label=f"{n}{state}: {row['dwell_points']} dwells{more}, {row['distance_m']:.1f} m")
            for j, k in enumerate(sorted(set(f.dwell[f.dwell >= 0].tolist()))):
                m = f.dwell == k
                # the dwells counted in the legend filled; one begun but not ended hollow
                done = ended is None or j < row["dwell_points"]
                ax.scatter(f.x[m].mean(), f.y[m].mean(), s=60, color=colour if done else "none", edgecolor="k",
                           zorder=3)
                ax.annotate(f"{n[-1]}.{k}", (f.x[m].mean(), f.y[m].mean()), xytext=(4, 4), textcoords="offset points",
                            fontsize=8)
        per_vehicle.append(row)
    ax.plot(est.x, est.y, "k+", ms=14, mew=2, label=f"joint estimate ({est.x:.2f}, {est.y:.2f})")
    if math.isfinite(est.sigma_m):
        _ellipse(ax, (est.x, est.y), cov, N_SIGMA_95, color="k", lw=1.0, ls="--")
    if truth:
        ax.plot(truth.sources[0].x, truth.sources[0].y, "r*", ms=14, label="truth")
    _map_frame(ax, any_ds.scenario)
    ax.set_title(wrapped_title(f"{len(names)} vehicles: error {err:.3f} m; {mission.get('reason', '')}",
                               ax.get_position().width * fig.get_figwidth(), 9),
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    _tight_layout(fig)
    with atomic_path(out / "report.png") as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    summary = {
        "error_m": err,
        "sigma_m": float(est.sigma_m),
        "ellipse_95": dict(est.ellipse_95 or {}),
        "bound_m": float(est.bound_m if est.bound_m is not None else math.nan),
        "p_value": float(est.p_value),
        "warnings": [],
        "estimate_source": "in-flight (joint)",
        "estimate": est.to_json(),
        "decided_by": decider,
        "dwell_points": sum(r["dwell_points"] for r in per_vehicle),
        "mission_time_s": float(mission.get("mission_time_s", math.nan)),
        "per_vehicle": per_vehicle,
        "truth": truth.to_dict() if truth else None,
        "stop_reason": mission.get("reason"),
        "outcome": mission.get("outcome"),
        "wall_time_s": wall_time_s,
        "speedup": speedup,
    }
    atomic_write_json(out / "summary.json", summary)
    return summary
