"""Campaigns: thousands of seeded in-process searches as Ray tasks, one Parquet row per flight.

A :class:`Sweep` is the cartesian product scenes x strategies x effects x swept search parameters x seeds;
each element is one *flight*: ``launch.offline.fly_offline`` (the same brain, in-flight estimator and
planner as ``radseek run``) run as one Ray task. :func:`run_campaign` runs a sweep on an embedded local
Ray (loopback only, no dashboard) or on an existing cluster (``address``), writes the rows to ``--out`` as
they come in (``parts/*.parquet``, merged into ``flights.parquet`` at the end: ``launch.campaign_store``), and
on a rerun flies only the flights that have no row yet. A flight that raises is a row with ``status = "error"``
and the error, never the end of the campaign. At the end: ``summary.md`` (one line per case) and the plots
``error_vs_dwells.png`` and ``coverage.png``.

This module sees the truth (``error_m``, ``covered_95``): it belongs with the launchers, not the mission.

Sweep parameters (``params``) are dotted names: ``SearchConfig`` fields (``max_dwells``, ``stop_sigma_m``,
``dwell.t_max``, ``next_best.gain_kind``, ...), ``odometry.<field>`` (``vehicle_sim.odometry.OdometryParams``)
and ``flight.speed`` / ``flight.yaw_rate_max`` (``fly_offline``). A list of values sweeps them; one value
sets them for every flight. Effects are ``"none"`` or ``"name"`` or ``"name:key=value,key=value"``
(``Scene.with_effect``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import signal
import socket
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from launch.campaign_store import DamagedStore, PartWriter, load_rows, merge
from launch.campaign_store import params_of as _params
from launch.campaign_store import salvage as salvage_file
from launch.ray_cluster import RayConnectError, start_ray
from radseek import __version__
from radseek.estimate import SourceEstimate
from radseek_io.outdir import OutputDirError, atomic_path, atomic_write_json, atomic_write_text, prepare_output

__all__ = ["CAMPAIGN_OUTPUTS", "CHI2_95_2D", "CampaignResult", "CampaignStopped", "DamagedStore", "RayConnectError",
           "Sweep", "fly_one", "load_rows", "parse_effect", "run_campaign", "summarize", "write_reports"]

#: chi-square 95 % quantile with 2 degrees of freedom (= -2 ln 0.05): the 95 % ellipse is d^2 <= this
CHI2_95_2D = -2.0 * math.log(0.05)
#: what a campaign writes in its folder (summaries first: ``--force`` removes them before the data)
CAMPAIGN_OUTPUTS = ("summary.md", "error_vs_dwells.png", "coverage.png", "flights.parquet", "parts", "campaign.json")


# ------------------------------------------------------------------------------------------------ sweep


def parse_effect(text: str) -> tuple[str, dict[str, Any]] | None:
    """``"none"`` -> None; ``"dead_time"`` -> ("dead_time", {}); ``"dead_time:tau_s=2e-5"`` -> (.., {tau_s: 2e-5})."""
    text = text.strip()
    if not text or text.lower() == "none":
        return None
    name, _, rest = text.partition(":")
    params: dict[str, Any] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, value = item.partition("=")
        if not eq:
            raise ValueError(f"effect parameter {item!r} in {text!r} is not key=value")
        params[key.strip()] = _scalar(value.strip())
    return name.strip(), params


def _scalar(text: str) -> Any:
    """A flag value as the TOML scalar it spells (number, bool, string)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


@dataclass
class Sweep:
    """What a campaign flies: every combination of ``scenes``, ``strategies``, ``effects``, swept ``params``
    and ``seeds``. ``params`` maps a dotted parameter name to a value or a list of values (swept)."""

    scenes: list[str] = field(default_factory=lambda: ["default"])
    strategies: list[str] = field(default_factory=lambda: ["active"])
    seeds: list[int] = field(default_factory=lambda: list(range(10)))
    effects: list[str] = field(default_factory=lambda: ["none"])
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from mission.search import STRATEGIES

        self.scenes, self.strategies, self.effects = list(self.scenes), list(self.strategies), list(self.effects)
        self.seeds = [int(s) for s in self.seeds]
        for s in self.strategies:
            if s not in STRATEGIES:
                raise ValueError(f"unknown strategy {s!r}; known: {', '.join(STRATEGIES)}")
        for e in self.effects:
            parse_effect(e)  # syntax only: a bad effect name or value is the flight's error, recorded
        for name in self.params:
            _check_param_name(name)
        if not (self.scenes and self.strategies and self.seeds and self.effects):
            raise ValueError("a sweep needs at least one scene, strategy, seed and effect")

    @classmethod
    def from_toml(cls, path: str | Path) -> Sweep:
        """Read ``[sweep]`` (scenes, strategies, seeds, effects) and ``[sweep.params]`` from a TOML file.
        ``seeds`` is a count (0..n-1), a list, or ``{start = a, stop = b}``."""
        data = tomllib.loads(Path(path).read_text())
        s = data.get("sweep", data)
        kwargs: dict[str, Any] = {k: s[k] for k in ("scenes", "strategies", "effects") if k in s}
        if "seeds" in s:
            kwargs["seeds"] = seeds_from(s["seeds"])
        kwargs["params"] = dict(s.get("params", {}))
        unknown = set(s) - {"scenes", "strategies", "effects", "seeds", "params"}
        if unknown:
            raise ValueError(f"{path}: unknown [sweep] keys {sorted(unknown)}")
        return cls(**kwargs)

    def swept(self) -> dict[str, list[Any]]:
        """Every parameter as a list of its values (one value: not swept, but still recorded)."""
        return {k: (list(v) if isinstance(v, list | tuple) else [v]) for k, v in sorted(self.params.items())}

    def cases(self) -> list[dict[str, Any]]:
        """The combinations without the seed: scene, strategy, effect and one value per parameter."""
        import itertools

        swept = self.swept()
        out = []
        for scene, strategy, effect in itertools.product(self.scenes, self.strategies, self.effects):
            for values in itertools.product(*swept.values()):
                out.append({"scene": scene, "strategy": strategy, "effect": effect,
                            "params": dict(zip(swept, values, strict=True))})
        return out

    def flights(self) -> list[dict[str, Any]]:
        """One spec per flight (``key`` identifies it across reruns), seed outermost: every case gets seed 0
        before any gets seed 1, so a campaign stopped part way is balanced across cases."""
        cases = self.cases()
        return [{**c, "seed": seed, "key": flight_key(c, seed)} for seed in self.seeds for c in cases]

    def fingerprint(self) -> str:
        """Identifies the sweep without its seeds: a rerun with more seeds resumes the same campaign."""
        return hashlib.sha256(_canonical({"scenes": self.scenes, "strategies": self.strategies,
                                          "effects": self.effects, "params": self.swept()}).encode()).hexdigest()[:16]

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def seeds_from(value: Any) -> list[int]:
    """Seeds from a count, a list, ``"a:b"`` or ``{start, stop}``."""
    if isinstance(value, int):
        return list(range(value))
    if isinstance(value, str):
        a, _, b = value.partition(":")
        return list(range(int(a), int(b))) if b else list(range(int(a)))
    if isinstance(value, Mapping):
        return list(range(int(value.get("start", 0)), int(value["stop"])))
    return [int(v) for v in value]


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def flight_key(case: Mapping[str, Any], seed: int) -> str:
    return hashlib.sha256(_canonical({**case, "seed": int(seed)}).encode()).hexdigest()[:20]


def _check_param_name(name: str) -> None:
    from mission.search import SearchConfig
    from vehicle_sim.odometry import OdometryParams

    head, _, rest = name.partition(".")
    if head == "flight":
        if rest not in ("speed", "yaw_rate_max"):
            raise ValueError(f"unknown parameter {name!r}: flight.speed or flight.yaw_rate_max")
        return
    obj: Any = OdometryParams() if head == "odometry" else SearchConfig()
    parts = rest.split(".") if head == "odometry" else name.split(".")
    for i, part in enumerate(parts):
        if not dataclasses.is_dataclass(obj) or part not in {f.name for f in dataclasses.fields(obj)}:
            raise ValueError(f"unknown parameter {name!r} (no field {'.'.join(parts[:i + 1])!r})")
        obj = getattr(obj, part)


def _replace_dotted(obj: Any, dotted: Mapping[str, Any]) -> Any:
    """``obj`` (a dataclass) with nested fields set from dotted names (validated by each __post_init__)."""
    top: dict[str, Any] = {}
    nested: dict[str, dict[str, Any]] = {}
    for name, value in dotted.items():
        head, _, rest = name.partition(".")
        if rest:
            nested.setdefault(head, {})[rest] = value
        else:
            top[head] = value
    for head, sub in nested.items():
        top[head] = _replace_dotted(getattr(obj, head), sub)
    return dataclasses.replace(obj, **top)


# ------------------------------------------------------------------------------------------------ one flight


_SCENES: dict[tuple[str, str], Any] = {}  # per worker process: (scene, effect) -> Scene


def _scene(name: str, effect: str, data: Mapping[str, Any] | None = None):
    """The scene ``name`` (from the driver's ``data`` if given: a cluster node may not have the file)
    with ``effect`` switched on, cached per worker process."""
    from detector_fw_sim.scene import load_scene, validate_scene

    key = (name, effect)
    if key not in _SCENES:
        scene = validate_scene(dict(data), name) if data is not None else load_scene(name)
        parsed = parse_effect(effect)
        if parsed is not None:
            scene = scene.with_effect(parsed[0], **parsed[1])
        _SCENES[key] = scene
    return _SCENES[key]


def coverage(estimate: SourceEstimate | None, truth_xy: Sequence[float]) -> tuple[float, bool | None]:
    """Mahalanobis distance^2 of the true source from the estimate under its x-y position covariance, and
    whether the 95 % ellipse covers the truth (d^2 <= chi2_2(0.95)); (nan, None) without an estimate or
    a finite covariance. A singular covariance (a collapsed ellipse) covers nothing off its line: d^2 = inf."""
    if estimate is None:
        return math.nan, None
    c = estimate.covariance[:2, :2]
    if not np.isfinite(c).all():
        return math.nan, None
    r = np.array([truth_xy[0] - estimate.x, truth_xy[1] - estimate.y], dtype=float)
    w, v = np.linalg.eigh(0.5 * (c + c.T))
    proj = v.T @ r
    with np.errstate(divide="ignore", invalid="ignore"):
        terms = np.where(w > 1e-18, proj**2 / np.where(w > 1e-18, w, 1.0), np.where(np.abs(proj) > 1e-12, np.inf, 0))
    d2 = float(terms.sum())
    return d2, bool(d2 <= CHI2_95_2D)


# bound_m is both a column of its own and est.bound_m (which benchmarks/mission_search.py reads)
_ESTIMATE_SKIP = {"x", "y", "z", "covariance", "sigma_m", "effects", "dwell", "converged"}


def fly_one(spec: Mapping[str, Any]) -> dict[str, Any]:
    """Fly one flight spec (see :meth:`Sweep.flights`) and return its row; never raises (an error is a row)."""
    t0, c0 = time.perf_counter(), time.process_time()
    row: dict[str, Any] = {"key": spec["key"], "scene": spec["scene"], "strategy": spec["strategy"],
                           "effect": spec["effect"], "seed": int(spec["seed"]),
                           **{f"p.{k}": v for k, v in spec["params"].items()},
                           "status": "ok", "error": None, "radseek_version": __version__,
                           "worker": f"{socket.gethostname()}:{os.getpid()}"}
    try:
        row.update(_fly(spec))
    except Exception as exc:  # noqa: BLE001 - a failed flight is recorded, not fatal to the campaign
        row["status"] = "error"
        row["error"] = f"{type(exc).__name__}: {exc}"[:2000]
    row["wall_s"] = time.perf_counter() - t0
    row["cpu_s"] = time.process_time() - c0
    row["finished_at"] = time.time()
    return row


def _fly(spec: Mapping[str, Any]) -> dict[str, Any]:
    from launch.offline import fly_offline
    from mission.search import SearchConfig
    from vehicle_sim.odometry import OdometryParams

    params = dict(spec["params"])
    flight = {k.split(".", 1)[1]: v for k, v in params.items() if k.startswith("flight.")}
    odo = {k.split(".", 1)[1]: v for k, v in params.items() if k.startswith("odometry.")}
    search = {k: v for k, v in params.items() if not k.startswith(("flight.", "odometry."))}
    config = _replace_dotted(SearchConfig(strategy=spec["strategy"]), search)
    odometry = _replace_dotted(OdometryParams(), odo) if odo else None
    scene = _scene(spec["scene"], spec["effect"], spec.get("scene_data"))
    r = fly_offline(scene, config, seed=int(spec["seed"]), odometry=odometry, **flight)
    est = r.estimate
    src = r.dataset.truth.sources[0]
    d2, covered = coverage(est, (src.x, src.y))
    out: dict[str, Any] = {
        "error_m": float(r.error_m),
        "sigma_m": float(est.sigma_m) if est else math.inf,
        "covered_95": covered, "mahalanobis2": d2,
        "dwell_points": len(r.dwell_rates), "search_dwells": int(r.brain.search_dwells),
        "check_dwells": int(r.brain.check_dwells),
        "mission_time_s": float(r.mission_time_s),
        "est_x": float(est.x) if est else math.nan, "est_y": float(est.y) if est else math.nan,
        "true_x": float(src.x), "true_y": float(src.y),
        "converged": est.converged if est else None,
        # the drift-aware bound (rms horizontal error reachable with the pose drift), when the estimate has it
        "bound_m": float(est.bound_m) if est and est.bound_m is not None else math.nan,
        "stop_reason": r.decisions[-1].reason,
        "outcome": None if r.decisions[-1].outcome is None else r.decisions[-1].outcome.value,  # a plain str
    }
    # whatever else the in-flight estimate reports rides along: numbers (e.g. a drift-aware bound) and the
    # numbers of nested records (e.g. an ellipse) as est.<key>[.<sub>]; another position covariance (e.g.
    # with the pose drift) gets its own coverage, covered_95.<suffix>
    for k, v in (est.to_json() if est else {}).items():
        if k in _ESTIMATE_SKIP:
            continue
        if _number(v):
            out[f"est.{k}"] = float(v)
        elif isinstance(v, Mapping):
            out.update({f"est.{k}.{kk}": float(vv) for kk, vv in v.items() if _number(vv)})
        elif k.startswith("covariance") and np.shape(v) == (3, 3):
            _, cov_k = coverage(est.replace(covariance=v), (src.x, src.y))
            out[f"covered_95.{k.removeprefix('covariance').strip('_') or k}"] = cov_k
    return out


def _number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


# ------------------------------------------------------------------------------------------------ progress


class Progress:
    """One status line on stderr: done/total, failures, rate, ETA (redrawn on a terminal, every 10 s
    otherwise)."""

    def __init__(self, total: int, done: int = 0, enabled: bool = True, stream=None):
        self.total, self.start_done, self.done, self.failed = total, done, done, 0
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.monotonic()
        self.last = 0.0

    def update(self, failed: bool = False) -> None:
        self.done += 1
        self.failed += int(failed)
        self.draw()

    def line(self) -> str:
        elapsed = time.monotonic() - self.t0
        new = self.done - self.start_done
        rate = new / elapsed if elapsed > 0 else 0.0
        left = self.total - self.done
        eta = _duration(left / rate) if rate > 0 else "?"
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        return (f"[{'#' * filled}{'-' * (width - filled)}] {self.done}/{self.total} flights"
                f"{f', {self.failed} failed' if self.failed else ''}  {rate * 60:.1f}/min  "
                f"elapsed {_duration(elapsed)}  ETA {eta}")

    def draw(self, final: bool = False) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if self.tty:
            self.stream.write("\r" + self.line() + ("\n" if final else ""))
            self.stream.flush()
        elif final or now - self.last >= 10.0:
            self.last = now
            self.stream.write(self.line() + "\n")
            self.stream.flush()


def _duration(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


# ------------------------------------------------------------------------------------------------ Ray


def _remote_fly():
    import ray

    return ray.remote(num_cpus=1, max_retries=2)(fly_one)


# ------------------------------------------------------------------------------------------------ campaign


class CampaignStopped(Exception):
    """The campaign was interrupted (Ctrl-C, SIGTERM); what finished is recorded, a rerun resumes."""


def scene_data(names: Iterable[str]) -> dict[str, dict[str, Any]]:
    """Each scene as the driver reads it (JSON-able), shipped with its flights so that cluster nodes fly
    the same scene without its file; an unreadable scene stops the campaign before anything flies."""
    from detector_fw_sim.scene import load_scene

    return {name: load_scene(name).model_dump(mode="json") for name in names}


@dataclass
class CampaignResult:
    out: Path
    rows: list[dict[str, Any]]
    flown: int  # flights flown by this run
    skipped: int  # flights already in the output
    wall_s: float
    workers: float  # CPUs Ray offered
    salvaged: list[tuple[Path, str, int, Path]] = field(default_factory=list)  # damaged file, problem, rows kept, aside


def open_campaign(sweep: Sweep, out: str | Path, force: bool = False) -> Path:
    """The campaign folder: new, the same sweep's (resumed), or refused (``OutputDirError``) unless
    ``force``, which removes the previous campaign's outputs."""
    out = Path(out)
    meta = out / "campaign.json"
    if out.is_dir() and any(out.iterdir()) and not force:
        try:
            fp = json.loads(meta.read_text())["fingerprint"]
        except (OSError, ValueError, KeyError):
            fp = None
        if fp is None:
            raise OutputDirError(f"output folder {out} is not empty and holds no campaign: choose another --out "
                                 f"or pass --force to replace its previous campaign outputs")
        if fp != sweep.fingerprint():
            raise OutputDirError(f"output folder {out} holds another sweep's campaign (fingerprint {fp}, this "
                                 f"sweep {sweep.fingerprint()}): choose another --out or pass --force to replace it")
        return out
    out = prepare_output(out, force=force, outputs=CAMPAIGN_OUTPUTS)
    return out


def run_campaign(sweep: Sweep, out: str | Path, *, workers: int | None = None, address: str | None = None,
                 force: bool = False, retry_failed: bool = False, progress: bool = True, quiet_ray: bool = True,
                 plots: bool = True, niceness: int | None = None, salvage: bool = False,
                 on_row: Callable[[dict[str, Any]], None] | None = None) -> CampaignResult:
    """Fly every flight of ``sweep`` not yet recorded in ``out`` (failed ones too with ``retry_failed``)
    as Ray tasks; write rows, summary and plots. Returns every row of the campaign. A damaged row file raises
    :class:`DamagedStore` before anything is written, unless ``salvage``: then its readable rows are kept, it is
    moved aside and its other flights are flown again (``CampaignResult.salvaged``)."""
    t0 = time.perf_counter()
    scenes = scene_data(sweep.scenes)
    out = open_campaign(sweep, out, force=force)
    salvaged: list[tuple[Path, str, int, Path]] = []
    try:
        recorded = load_rows(out)
    except DamagedStore as exc:
        if not salvage:
            raise
        salvaged = [(d.path, d.problem, len(d.rows), salvage_file(out, d)) for d in exc.damaged]
        recorded = load_rows(out)
    atomic_write_json(out / "campaign.json", {
        "fingerprint": sweep.fingerprint(), "sweep": sweep.to_dict(), "radseek_version": __version__,
        "address": address, "workers": workers})
    done = {r["key"]: r for r in recorded}
    todo = [f for f in sweep.flights()
            if f["key"] not in done or (retry_failed and done[f["key"]]["status"] != "ok")]
    todo = [{**f, "scene_data": scenes[f["scene"]]} for f in todo]
    total = len(sweep.flights())
    skipped = total - len(todo)
    cpus = 0.0
    if todo:
        cpus = _run_tasks(todo, out, workers, address, Progress(total, skipped, enabled=progress), quiet_ray, on_row,
                          niceness)
    rows = merge(out)
    keys = {f["key"] for f in sweep.flights()}
    rows_sweep = [r for r in rows if r["key"] in keys]
    write_reports(rows_sweep, out, sweep, plots=plots)
    return CampaignResult(out, rows_sweep, len(todo), skipped, time.perf_counter() - t0, cpus, salvaged)


def _run_tasks(todo: list[dict[str, Any]], out: Path, workers: int | None, address: str | None,
               bar: Progress, quiet_ray: bool, on_row: Callable | None, niceness: int | None = None) -> float:
    reaper = start_ray(workers, address, quiet=quiet_ray, niceness=niceness)
    import ray

    writer = PartWriter(out)
    bar.t0 = time.monotonic()  # rate and ETA from the first task on, not from Ray's start-up
    # Ctrl-C / SIGTERM: stop cleanly (rows so far written, tasks cancelled, Ray shut down); a rerun resumes.
    # Own handlers, because a KeyboardInterrupt does not reliably get out of Ray's blocking calls.
    stop: list[int] = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda signum, frame: stop.append(signum))
    try:
        cpus = float(ray.cluster_resources().get("CPU", 1))
        window = max(4, int(2 * cpus))  # tasks in flight: every CPU busy, the queue bounded
        remote = _remote_fly()
        pending: dict[Any, dict[str, Any]] = {}
        queue = list(reversed(todo))
        bar.draw()
        while (queue or pending) and not stop:
            while queue and len(pending) < window:
                spec = queue.pop()
                pending[remote.remote(spec)] = spec
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)
            for ref in ready:
                spec = pending.pop(ref)
                try:
                    row = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - the worker died (OOM, node lost): record it
                    row = {**fly_error_row(spec), "error": f"{type(exc).__name__}: {exc}"[:2000]}
                writer.add(row)
                if on_row is not None:
                    on_row(row)
                bar.update(failed=row["status"] != "ok")
            if not ready:
                bar.draw()
        bar.draw(final=True)
        if stop:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise CampaignStopped(f"stopped by signal {stop[0]}: {bar.done} of {bar.total} flights recorded in "
                                  f"{out}; run the same command again to resume")
        return cpus
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        writer.flush()
        ray.shutdown()
        if reaper is not None:
            reaper.close()  # what ray.shutdown() left (its agents) and the temporary folder


def fly_error_row(spec: Mapping[str, Any]) -> dict[str, Any]:
    return {"key": spec["key"], "scene": spec["scene"], "strategy": spec["strategy"], "effect": spec["effect"],
            "seed": int(spec["seed"]), **{f"p.{k}": v for k, v in spec["params"].items()},
            "status": "error", "error": None, "radseek_version": __version__, "worker": None,
            "wall_s": math.nan, "cpu_s": math.nan, "finished_at": time.time()}


# ------------------------------------------------------------------------------------------------ reports


def _case_of(row: Mapping[str, Any]) -> tuple:
    return (row["scene"], row["strategy"], row["effect"], _canonical(_params(row)))


def median_ci(x: np.ndarray, level: float = 0.95) -> tuple[float, float, float, float]:
    """Median with its distribution-free confidence interval: order statistics (x_(r), x_(n+1-r)) with the largest
    r whose exact coverage, P(r <= B <= n - r) for B ~ Binomial(n, 1/2), is at least ``level``. Returns (median,
    lower, upper, coverage). Below the smallest n that reaches ``level`` (6 for 95 %: [min, max] of 5 covers only
    93.75 %) the bounds are nan and the coverage is that of [min, max], so no interval claims more than it has."""
    from scipy import stats

    x = np.sort(np.asarray(x, dtype=float))
    n = len(x)
    if n == 0:
        return math.nan, math.nan, math.nan, math.nan
    med = float(np.median(x))
    r = np.arange(1, n // 2 + 1)  # x_(r) .. x_(n+1-r), 1-based
    cover = stats.binom.cdf(n - r, n, 0.5) - stats.binom.cdf(r - 1, n, 0.5)
    ok = np.flatnonzero(cover >= level)
    if len(ok) == 0:
        return med, math.nan, math.nan, float(cover[0]) if len(cover) else 0.0
    k = int(r[ok[-1]])
    return med, float(x[k - 1]), float(x[n - k]), float(cover[ok[-1]])


def _ci_text(lo: float, hi: float, coverage: float) -> str:
    """``[lo, hi]``, with its exact coverage when it is not the nominal 95 %, or why there is none."""
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return f"[no 95 % CI: too few flights; [min, max] covers {coverage:.1%}]" if math.isfinite(coverage) else ""
    return f"[{lo:.3f}, {hi:.3f}] ({coverage:.1%})"


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score 95 % interval of a proportion k/n."""
    if n == 0:
        return math.nan, math.nan
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


def summarize(rows: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One record per case (scene, strategy, effect, parameters) over its seeds."""
    groups: dict[tuple, list[Mapping[str, Any]]] = {}
    for r in rows:
        groups.setdefault(_case_of(r), []).append(r)
    out = []
    for case, rs in sorted(groups.items()):
        ok = [r for r in rs if r["status"] == "ok" and r.get("error_m") is not None]
        err = np.array([r["error_m"] for r in ok], dtype=float)
        cov = [r["covered_95"] for r in ok if r.get("covered_95") is not None]
        finite = err[np.isfinite(err)]
        bounds = np.array([r.get("bound_m", math.nan) for r in ok], dtype=float)
        rec = {"scene": case[0], "strategy": case[1], "effect": case[2], "params": json.loads(case[3]),
               "flights": len(rs), "failed": len(rs) - len(ok), "estimated": int(len(finite)),
               "median_error_m": median_ci(finite)[0] if len(finite) else math.nan,
               "median_error_ci": median_ci(finite)[1:3] if len(finite) else (math.nan, math.nan),
               "median_error_ci_coverage": median_ci(finite)[3] if len(finite) else math.nan,
               "p90_error_m": float(np.percentile(finite, 90)) if len(finite) else math.nan,
               "median_sigma_m": float(np.median([r["sigma_m"] for r in ok])) if ok else math.nan,
               "median_bound_m": float(np.nanmedian(bounds)) if np.isfinite(bounds).any() else math.nan,
               "coverage_95": (sum(cov) / len(cov)) if cov else math.nan, "coverage_n": len(cov),
               "coverage_ci": wilson(sum(cov), len(cov)),
               "median_dwells": float(np.median([r["dwell_points"] for r in ok])) if ok else math.nan,
               "median_search_dwells": float(np.median([r["search_dwells"] for r in ok])) if ok else math.nan,
               "median_mission_s": float(np.median([r["mission_time_s"] for r in ok])) if ok else math.nan,
               "mean_wall_s": float(np.nanmean([r["wall_s"] for r in rs])) if rs else math.nan,
               "mean_cpu_s": float(np.nanmean([r["cpu_s"] for r in rs])) if rs else math.nan}
        out.append(rec)
    return out


def summary_markdown(summary: list[dict[str, Any]], meta: Mapping[str, Any] | None = None) -> str:
    lines = ["# Campaign summary", ""]
    if meta:
        lines += [f"radseek {meta.get('radseek_version')}, sweep fingerprint {meta.get('fingerprint')}, "
                  f"{meta.get('flights')} flights in the output", ""]
    lines += ["| scene | strategy | effect | parameters | flights | failed | median error (m) [95 % CI] "
              "| p90 error (m) | median sigma (m) | median drift-aware bound (m) "
              "| 95 % ellipse coverage [95 % CI] | median dwells (search) "
              "| median mission (s) | wall / flight (s) | CPU / flight (s) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        params = ", ".join(f"{k[2:]}={v}" for k, v in s["params"].items()) or "-"
        lo, hi = s["median_error_ci"]
        clo, chi = s["coverage_ci"]
        cov = (f"{s['coverage_95']:.2f} [{clo:.2f}, {chi:.2f}] (n={s['coverage_n']})"
               if s["coverage_n"] else "-")
        lines.append(
            f"| {s['scene']} | {s['strategy']} | {s['effect']} | {params} | {s['flights']} | {s['failed']} "
            f"| {s['median_error_m']:.3f} {_ci_text(lo, hi, s.get('median_error_ci_coverage', math.nan))} "
            f"| {s['p90_error_m']:.3f} | {s['median_sigma_m']:.3f} "
            f"| {s['median_bound_m']:.3f} "
            f"| {cov} | {s['median_dwells']:.0f} ({s['median_search_dwells']:.0f}) | {s['median_mission_s']:.0f} "
            f"| {s['mean_wall_s']:.1f} | {s['mean_cpu_s']:.1f} |")
    return "\n".join(lines) + "\n"


def write_reports(rows: list[dict[str, Any]], out: Path, sweep: Sweep | None = None, plots: bool = True) -> None:
    """``summary.md`` and (with ``plots``) ``error_vs_dwells.png`` and ``coverage.png`` in ``out``."""
    summary = summarize(rows)
    meta = {"radseek_version": __version__, "fingerprint": sweep.fingerprint() if sweep else None,
            "flights": len(rows)}
    failures = [r for r in rows if r["status"] != "ok"]
    text = summary_markdown(summary, meta)
    if failures:
        text += "\n## Failed flights\n\n| scene | strategy | effect | seed | error |\n|---|---|---|---|---|\n"
        text += "".join(f"| {r['scene']} | {r['strategy']} | {r['effect']} | {r['seed']} | "
                        f"{str(r['error']).splitlines()[0][:200] if r['error'] else '?'} |\n" for r in failures[:50])
        if len(failures) > 50:
            text += f"\n... and {len(failures) - 50} more (see flights.parquet)\n"
    atomic_write_text(out / "summary.md", text)
    if plots and rows:
        _plot_error_vs_dwells(rows, out / "error_vs_dwells.png")
        _plot_coverage(summary, out / "coverage.png")


def _plot_error_vs_dwells(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    ok = [r for r in rows if r["status"] == "ok" and math.isfinite(r["error_m"])]
    scenes = sorted({r["scene"] for r in rows})
    varied = sorted({k for r in ok for k in _params(r) if len({str(x.get(k)) for x in ok}) > 1})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4.2), squeeze=False)
    for ax, scene in zip(axes[0], scenes, strict=True):
        series: dict[str, list] = {}
        for r in ok:
            if r["scene"] == scene:
                label = r["strategy"] + ("" if r["effect"] == "none" else f" {r['effect']}")
                if varied:
                    label += " " + ",".join(f"{k[2:]}={r.get(k)}" for k in varied)
                series.setdefault(label, []).append((r["dwell_points"], r["error_m"]))
        for label, pts in sorted(series.items()):
            a = np.array(pts, dtype=float)
            ks = np.unique(a[:, 0])
            stats_ = [(k, *median_ci(a[a[:, 0] == k, 1])[:3], int((a[:, 0] == k).sum())) for k in ks]
            st = np.array([s for s in stats_ if s[4] >= 3] or stats_, dtype=float)
            line, = ax.plot(st[:, 0], st[:, 1], "o-", label=f"{label} (n={len(a)})")
            ax.fill_between(st[:, 0], st[:, 2], st[:, 3], color=line.get_color(), alpha=0.2)
            ax.errorbar(st[:, 0], st[:, 1], yerr=[st[:, 1] - st[:, 2], st[:, 3] - st[:, 1]], fmt="none",
                        color=line.get_color(), capsize=3)  # the band of a single dwell count is a bar
            ax.scatter(a[:, 0] + np.random.default_rng(0).uniform(-0.15, 0.15, len(a)), a[:, 1], s=4,
                       color=line.get_color(), alpha=0.25)
        ax.set_yscale("log")
        ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
        ax.set_xlabel("dwell points flown")
        ax.set_ylabel("position error (m)")
        ax.set_title(f"{scene}: median error, 95 % CI of the median")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def _plot_coverage(summary: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [s for s in summary if s["coverage_n"]]
    fig, ax = plt.subplots(figsize=(max(5.0, 0.9 * len(rows) + 2), 4.2))
    if rows:
        x = np.arange(len(rows))
        cov = np.array([s["coverage_95"] for s in rows])
        ci = np.array([s["coverage_ci"] for s in rows])
        ax.bar(x, cov, color="tab:blue", alpha=0.7)
        ax.errorbar(x, cov, yerr=[cov - ci[:, 0], ci[:, 1] - cov], fmt="none", color="k", capsize=3)
        ax.set_xticks(x, [f"{s['scene']}\n{s['strategy']}" + ("" if s["effect"] == "none" else f"\n{s['effect']}")
                          for s in rows], fontsize=7)
    ax.axhline(0.95, color="tab:red", ls="--", label="nominal 95 %")
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("truth inside the 95 % ellipse")
    ax.set_title("95 % ellipse coverage (Wilson 95 % CI)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
