"""The measurement model diagnose fits: the estimator's composable model (``estimator.model``) and its Poisson
maximum-likelihood fit (``estimator.mle``), with a cache of fits per effect set.
``gain_drift`` is never part of the count model: total counts barely change when the gain drifts, so it lives
in ``estimator.spectral`` and its likelihood is a separate factor.
"""

from __future__ import annotations

import gc
import hashlib
import os
import pickle
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from estimator.mle import fit
from estimator.model import COUNT_EFFECTS, OPEN_WORLD_EFFECTS, MeasurementModel, UnmappedWall
from radseek.dataset import EFFECTS, Frames, Scenario

#: an unmapped wall is fitted in full only when its shadow screen's best LR reaches this share of the LR its test
#: needs at the step's threshold
SCREEN_GATE = 0.2
#: bump when a saved diagnosis (``CountFitter.save``) can no longer be reused as it is
CACHE_FORMAT = 1
SPECTRAL_EFFECTS = ("gain_drift",)
#: effects on the counts' variance only (``estimator.diagnose.dispersion``); not in the dataset spec's table
#: (the emulator's scene format mirrors that table), so diagnose's vocabulary extends it here
VARIANCE_EFFECTS = ("over_dispersion",)
#: effects that are not part of the count model's mean: each has its own likelihood factor or test
NON_COUNT_EFFECTS = SPECTRAL_EFFECTS + VARIANCE_EFFECTS
#: every effect diagnose can name, in report order: the dataset spec's base table, a wall the map lacks (the
#: spec's ``unmapped_wall``; ``unmapped_wall_2`` is a second one, offered once the first is in) and the variance
#: effect
VOCABULARY: tuple[str, ...] = (*EFFECTS, *OPEN_WORLD_EFFECTS, *VARIANCE_EFFECTS)
#: the unmapped walls, first and second
WALLS = OPEN_WORLD_EFFECTS


@lru_cache(maxsize=1)
def _code_hash() -> str:
    """A hash of the estimator's source: fits saved by another version of the model or the selection are not
    reused (``CountFitter.fingerprint``)."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(path.read_bytes())
    return h.hexdigest()


def count_key(effects: Iterable[str]) -> tuple[str, ...]:
    """The count-model effects of ``effects`` in the order fits are keyed by."""
    effects = set(effects)
    return tuple(e for e in COUNT_EFFECTS if e in effects)


def split_effects(effects: Iterable[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(count-model effects, other effects: spectral and variance), in vocabulary order, duplicates removed."""
    effects = list(dict.fromkeys(effects))
    for e in effects:
        if e not in VOCABULARY:
            raise ValueError(f"unknown effect {e!r}; known: {', '.join(VOCABULARY)}")
    count = tuple(e for e in VOCABULARY if e in effects and e not in NON_COUNT_EFFECTS)
    spec = tuple(e for e in VOCABULARY if e in effects and e in NON_COUNT_EFFECTS)
    return count, spec


def split_transit_legs(frames: Frames, turn_deg: float = 25.0, k: int = 3) -> Frames:
    """Frames whose transit runs are split into straight legs (dwell -1 / -2 alternating per leg).

    The estimator's fit gives every dwell and every contiguous transit run one uncertain position offset.
    A navigation error is not constant over a transit run that turns (a low pass, a lawnmower line and its
    turn): with one offset per run, the leftover pose error of a run near a strong source is structured in
    time and a time-like effect (pose_drift) takes it up. Splitting the runs at turns (the direction of motion,
    smoothed over +-k frames, changes by more than ``turn_deg``) gives each leg its own offset. Only the
    ``dwell`` column changes, and only for transit frames.
    """
    dw = np.asarray(frames.dwell).copy()
    moving = dw < 0
    if not moving.any() or len(frames) < 2 * k + 2:
        return frames
    pos = frames.positions
    n = len(frames)
    i = np.arange(n)
    v = pos[np.minimum(i + k, n - 1)] - pos[np.maximum(i - k, 0)]
    u = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
    before = u[np.maximum(i - k, 0)]
    after = u[np.minimum(i + k, n - 1)]
    run_start = np.r_[True, moving[1:] != moving[:-1]]
    run = np.cumsum(run_start)
    inside = (run[np.maximum(i - 2 * k, 0)] == run) & (run[np.minimum(i + 2 * k, n - 1)] == run)
    turning = (np.einsum("ij,ij->i", before, after) < np.cos(np.radians(turn_deg))) & moving & inside
    # a leg boundary in the middle of each contiguous turning stretch
    edges = np.diff(np.r_[0, turning.astype(int), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    cut = np.zeros(n, dtype=bool)
    cut[(starts + ends) // 2] = True
    leg = np.cumsum(cut | run_start)
    dw[moving] = -1 - (leg[moving] % 2)
    return replace(frames, dwell=dw)


def progress(msg: str, quiet: bool = False) -> None:
    if not quiet:
        print(f"[diagnose {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def progress_bar(label: str, done: int, total: int, t0: float, quiet: bool = False, width: int = 20) -> None:
    """One line per completed task: ``label [#####-----] 5/10 (12 s)``."""
    if not quiet:
        k = int(round(width * done / max(total, 1)))
        progress(f"{label} [{'#' * k}{'-' * (width - k)}] {done}/{total} ({time.perf_counter() - t0:.0f} s)")


@dataclass
class FitTask:
    """One count-model fit for ``CountFitter.fit_many``."""

    effects: tuple[str, ...]
    init: dict[str, float] | None = None
    n_starts: int | None = None
    label: str = ""
    cache: bool = True
    #: also start from the second source's best grid cell (``estimator.mle.fit(second_grid=True)``)
    second_grid: bool = False


_WORKER: dict[str, Any] = {}


def _worker_init(fitter: CountFitter, extra: dict[str, Any]) -> None:
    _WORKER["fitter"] = fitter
    _WORKER.update(extra)


def _worker_fit(task: FitTask) -> tuple[Any, dict[tuple[str, ...], Any]]:
    from estimator.diagnose.threads import blas_threads

    with blas_threads(1):
        return _WORKER["fitter"].isolated_fit(task, _WORKER["cache"])


def _worker_call(name: str) -> Any:
    from estimator.diagnose.threads import blas_threads

    with blas_threads(1):
        return _WORKER[name]()


def _shadow_label(label: str) -> str:
    return label if label.endswith("(shadow start)") else f"{label} (shadow start)"


@dataclass
class CountFitter:
    """Fits count models by effect set (cached), with pose uncertainty, reporting progress on stderr."""

    scenario: Scenario
    frames: Frames
    n_starts: int = 8
    seed: int = 0
    quiet: bool = False
    jobs: int = 1  # processes for fit_many (candidate fits); 1 = in this process
    #: the p-value an effect must beat at the current selection step (alpha / candidates): an unmapped wall whose
    #: shadow screen is far from what that needs is not fitted in full (``_fit_wall``)
    wall_threshold: float | None = None
    #: parameters held at their start values (a selection step holds the placements of the unmapped walls and of
    #: the second source already in the model while it tests other effects: the LR is then a lower bound, and a
    #: walled fit costs a third); fits with held parameters are not cached
    hold: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        self.fit_frames = split_transit_legs(self.frames)
        self._cache: dict[tuple[str, ...], Any] = {}
        #: forward selections already run, by (start effects, alpha, steps): ``--add`` reuses the baseline's
        self.selections: dict[tuple[Any, ...], Any] = {}
        #: the spectral fit, once computed (``runner.LazySpectral``)
        self.spectral: Any = None

    # ---- a saved diagnosis: ``radseek diagnose --add`` after a first run reuses its fits and selection

    def fingerprint(self) -> str:
        """What the fits depend on: the frames, the scenario, the fit settings and the cache format."""
        h = hashlib.sha256(f"{CACHE_FORMAT}|{self.n_starts}|{self.seed}|{self.scenario!r}|{_code_hash()}".encode())
        for name in self.frames.__dataclass_fields__:
            h.update(np.ascontiguousarray(getattr(self.frames, name)).tobytes())
        return h.hexdigest()

    def save(self, path: Path) -> None:
        """Write the fits, selections and spectral fit to ``path`` (atomically: a reader never sees half)."""
        tmp = path.with_name(path.name + ".tmp")
        with tmp.open("wb") as fh:
            pickle.dump({"fingerprint": self.fingerprint(), "fits": self._cache, "selections": self.selections,
                         "spectral": self.spectral}, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)

    def load(self, path: Path) -> bool:
        """Reuse a saved diagnosis of the same data and settings; False (and nothing loaded) otherwise."""
        try:
            with path.open("rb") as fh:
                saved = pickle.load(fh)
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError, ValueError):
            return False
        if not isinstance(saved, dict) or saved.get("fingerprint") != self.fingerprint():
            return False
        self._cache.update(saved["fits"])
        self.selections.update(saved["selections"])
        self.spectral = saved["spectral"]
        return True

    def model(self, effects: tuple[str, ...]) -> MeasurementModel:
        return MeasurementModel(self.scenario, effects=tuple(effects))

    def fit(self, effects: tuple[str, ...], init: dict[str, float] | None = None, n_starts: int | None = None,
            label: str = "", cache: bool = True, more_inits: list[dict[str, float]] | None = None,
            second_grid: bool = False) -> Any:
        """Fit the model with ``effects``; the best fit per effect set is kept and returned next time.
        ``more_inits``: further starts beside ``init``; ``second_grid``: the second source's best grid cell is
        one of them (``estimator.mle.fit``)."""
        key = count_key(effects)
        if cache and key in self._cache and not getattr(self._cache[key], "screened_only", False):
            return self._cache[key]
        for wall in WALLS:
            if wall in key and not (init and f"{wall}.r" in init):
                return self._fit_wall(key, wall, init, label, cache)
        t0 = time.perf_counter()
        model = self.model(key)
        names = set(model.param_names)
        init = {k: float(v) for k, v in (init or {}).items() if k in names}
        more = [{k: float(v) for k, v in st.items() if k in names} for st in more_inits or []]
        held = {k: init[k] for k in self.hold if k in init}
        if held:
            model = model.with_params(**{k: {"value": v, "fixed": True} for k, v in held.items()})
        res = fit(model, self.fit_frames, n_starts=n_starts or self.n_starts, seed=self.seed,
                        pose_uncertainty=True, init=init or None, more_inits=more, hover=True,
                        second_grid=second_grid)
        progress(f"fitted {label or describe(key)}: nll {res.nll:.1f}, deviance/dof {res.deviance_per_dof:.3f} "
                 f"({time.perf_counter() - t0:.1f} s)", self.quiet)
        if held:
            res.held = tuple(held)
        elif key not in self._cache or res.nll < self._cache[key].nll:
            self._cache[key] = res
        return res

    def isolated_fit(self, task: FitTask, start: dict[tuple[str, ...], Any]) -> tuple[Any, dict[tuple[str, ...], Any]]:
        """Fit ``task`` (uncached) from the cache ``start`` alone; returns the fit and the fits it added on the way."""
        self._cache = dict(start)
        res = self.fit(task.effects, init=task.init, n_starts=task.n_starts, label=task.label, cache=False,
                       second_grid=task.second_grid)
        return res, {k: v for k, v in self._cache.items() if start.get(k) is not v}

    def _fit_wall(self, key: tuple[str, ...], wall: str, init: dict[str, float] | None, label: str, cache: bool
                  ) -> Any:
        """Fit a model with an unmapped wall from the best placements of its shadow screen
        (``estimator.diagnose.shadow``) given the fit without it; the result carries ``wall_looks``, the number
        of placements screened (the test's look-elsewhere factor)."""
        from estimator.diagnose.shadow import screen

        inner = tuple(e for e in key if e != wall and not (wall == "unmapped_wall" and e == "unmapped_wall_2"))
        base = self.fit(inner, init=init)
        th = dict(base.values)
        zero = {k: 0.0 for k in ("cps_at_1m", "second_source.cps_at_1m") if k in th}
        background = self.model(inner).expected_counts({**th, **zero}, self.fit_frames)
        exclude = [UnmappedWall.wall_of(th, w) for w in WALLS if w != wall and f"{w}.r" in th]
        src = np.array([th["x"], th["y"], th.get("z", self.scenario.source_z)])
        pl = screen(self.fit_frames, base.expected, background, src, self.scenario.bounds_min,
                    self.scenario.bounds_max, np.array(exclude) if exclude else None)
        starts = pl.best(src[:2], 3)
        top = float(pl.lr.max()) if len(pl.lr) else 0.0
        thr = self.wall_threshold
        needed = float(stats.chi2.isf(min(2.0 * thr / max(pl.scored, 1), 1.0), 1)) if thr is not None else 0.0
        progress(f"{wall}: {pl.scored} placements screened, best shadow LR {top:.1f}"
                 + (f" (significant from ~{needed:.0f})" if thr is not None else ""), self.quiet)
        if not starts or (self.wall_threshold is not None and top < SCREEN_GATE * needed):
            # the screen holds the source; a wall the data call for shows there at a third or more of its full
            # LR (lattice-wall unmapped: 149 against 522), so one this far below cannot become significant:
            # report the screen's LR (a lower bound of the full fit's) without fitting in full
            return self._screened_only(base, wall, starts[0] if starts else {}, top, pl.scored)
        # runner-up placements whose shadow explains less than half of the best one's are not fitted in full
        starts = [st for st, lr in zip(starts, pl.best_lr, strict=True) if lr >= 0.5 * pl.best_lr[0]]
        # every kept placement starts one fit: screened there without pose offsets, the best basins searched in
        # full (three full fits, one per placement, cost three times as much and mostly found the same minimum)
        inits = [{**th, **(init or {}), **{f"{wall}.{k}": v for k, v in st.items()}} for st in starts or [{}]]
        best = self.fit(key, init=inits[0], more_inits=inits[1:], n_starts=len(inits),
                        label=_shadow_label(label or describe(key)), cache=cache)
        best.wall_looks = pl.scored
        return best

    def _screened_only(self, base: Any, wall: str, start: dict[str, float], lr: float, looks: int) -> Any:
        """The fit without the wall, carrying the wall's best screened placement and the screen's LR (nll lowered
        by LR / 2): a candidate that was not fitted in full (``screened_only``)."""
        model = self.model((*base.model.effects, wall))
        values = {**model.defaults(), **base.values, **{f"{wall}.{k}": float(v) for k, v in start.items()}}
        res = replace(base, model=model, values=values, nll=base.nll - lr / 2,
                      free_names=[*base.free_names, *(n for n in model.free_names if n.startswith(wall + "."))],
                      errors={**base.errors, **{n: float("nan") for n in model.free_names if n.startswith(wall + ".")}})
        res.wall_looks = looks
        res.screened_only = True
        return res

    def fit_many(self, tasks: list[FitTask], side: dict[str, Any] | None = None, label: str = "fits"
                 ) -> tuple[list[Any], dict[str, Any]]:
        """Fit every task (in ``jobs`` forked processes when > 1), with a progress bar; ``side`` maps names to
        zero-argument callables run alongside (the spectral fit). Returns (fit results in task order, side
        results). Results are cached like ``fit`` (tasks with ``cache=False`` are not)."""
        side = side or {}
        t0 = time.perf_counter()
        total = len(tasks) + len(side)
        done = 0
        out: list[Any] = [None] * len(tasks)
        side_out: dict[str, Any] = {}
        todo = []
        # every task sees the cache as it was when the batch began, in a worker or here, so that a task's fit does not
        # depend on which tasks ran before it (with --jobs 1 a wall candidate's inner fit came from its siblings'
        # cache, in a worker from the empty one: the two named different effects on the same flight)
        start = self._cache
        found: dict[int, dict[tuple[str, ...], Any]] = {}
        for i, task in enumerate(tasks):
            key = count_key(task.effects)
            if task.cache and key in self._cache and not getattr(self._cache[key], "screened_only", False):
                out[i] = self._cache[key]
                done += 1
            else:
                todo.append(i)
        if self.jobs > 1 and len(todo) + len(side) > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor, as_completed

            ctx = mp.get_context("fork")
            # the caller's garbage is collected here, where its threads live, and what is left is frozen out of the
            # workers' collections: a forked worker otherwise ran an inherited cycle's finalizer that waited on a
            # thread the fork did not copy, and spun on it (a whole make test hung 8 min on one diagnose)
            gc.collect()
            gc.freeze()
            try:
                with ProcessPoolExecutor(min(self.jobs, len(todo) + len(side)), mp_context=ctx,
                                         initializer=_worker_init,
                                         initargs=(replace(self, quiet=True, jobs=1), {**side, "cache": start})
                                         ) as ex:
                    futs = {ex.submit(_worker_call, name): ("side", name) for name in side}
                    futs.update({ex.submit(_worker_fit, tasks[i]): ("fit", i) for i in todo})
                    for fut in as_completed(futs):
                        kind, ref = futs[fut]
                        if kind == "side":
                            side_out[ref] = fut.result()
                        else:
                            out[ref], found[ref] = fut.result()
                        done += 1
                        progress_bar(label, done, total, t0, self.quiet)
            finally:
                gc.unfreeze()
        else:
            for name, fn in side.items():
                side_out[name] = fn()
                done += 1
                progress_bar(label, done, total, t0, self.quiet)
            for i in todo:
                out[i], found[i] = self.isolated_fit(tasks[i], start)
                done += 1
                progress_bar(label, done, total, t0, self.quiet)
            self._cache = start
        for i in todo:  # the fits the tasks made on the way (an unmapped wall's inner fit), in task order
            for key, res in found[i].items():
                if key not in self._cache or res.nll < self._cache[key].nll:
                    self._cache[key] = res
        for i in todo:
            key = count_key(tasks[i].effects)
            if tasks[i].cache and not getattr(out[i], "screened_only", False) and not getattr(out[i], "held", ()) and \
                    (key not in self._cache or out[i].nll < self._cache[key].nll):
                self._cache[key] = out[i]
        return out, side_out


def describe(effects: Iterable[str]) -> str:
    effects = list(effects)
    return "baseline" + "".join(f" + {e}" for e in effects)
