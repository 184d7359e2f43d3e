"""The one localizer interface (scikit-learn estimator contract, shared/style-examples.md section 4).

- The constructor only stores its keyword settings, unchanged; no work, no validation beyond types.
  ``get_params()`` reads them back from the constructor signature, ``clone(loc)`` makes an unfitted copy,
  ``set_params(**kw)`` changes them.
- ``fit(data, scenario=None) -> self`` with ``data`` a :class:`radseek.dataset.Dataset` (its truth is never
  read) or :class:`radseek.dataset.Frames` plus a :class:`radseek.dataset.Scenario`.
- Results live in attributes with a trailing underscore, set only by fitting:
  ``sources_`` (list of ``{"x", "y", "z", "cps_at_1m"}``), ``covariance_`` (4M x 4M over
  (x, y, z, cps_at_1m) of each of the M sources in turn; ``to_estimate`` sends its diagonal 4 x 4 blocks,
  the layout of :class:`radseek.topics.Estimate`), ``background_`` (cps), ``crlb_`` (same layout as
  ``covariance_``, or None when the method has no bound).
- ``partial_fit(frames, scenario=None)`` feeds more frames of the same flight. The sequential filter
  (``pf``: also ``update(position, counts, duration)`` per measurement) updates in place; the others refit
  on everything seen so far (``multi-pf`` recomputes every particle's eq. 3.11 intensity from all data anyway).

Localizers get the operator's knowledge (``Scenario``) and the frames, never the truth: the
isolation RadInterAct-style benchmarks rely on.
"""

from __future__ import annotations

import copy
import importlib
import inspect
from typing import Any, ClassVar

import numpy as np

from estimator.dwell_summary import concat_frames
from radseek.dataset import Dataset, Frames, Scenario
from radseek.topics import ESTIMATE_STATE, Estimate

__all__ = ["Localizer", "NotFittedError", "clone", "make_localizer", "LOCALIZERS", "as_frames_scenario",
           "source_dict"]

#: registry: method name -> "module:Class" (imported lazily, so ``sphere`` does not pay for iminuit)
LOCALIZERS: dict[str, str] = {
    "sphere": "estimator.localizers.sphere_intersection:SphereIntersection",
    "pf": "estimator.localizers.particle_filter:ParticleFilter",
    "multi-pf": "estimator.localizers.multi_source_pf:MultiSourceParticleFilter",
    "gp": "estimator.localizers.gaussian_process:GaussianProcessLocalizer",
    "mle": "estimator.localizers.mle:MaximumLikelihood",
}


class NotFittedError(RuntimeError):
    """A result was asked of a localizer that has not been fitted."""


def source_dict(x: float, y: float, z: float, cps_at_1m: float) -> dict[str, float]:
    return {"x": float(x), "y": float(y), "z": float(z), "cps_at_1m": float(cps_at_1m)}


def as_frames_scenario(data: Dataset | Frames, scenario: Scenario | None = None) -> tuple[Frames, Scenario]:
    """Frames and scenario from a Dataset (truth dropped here) or from Frames plus a Scenario."""
    if isinstance(data, Dataset):
        return data.frames, scenario if scenario is not None else data.scenario
    if isinstance(data, Frames):
        if scenario is None:
            raise TypeError("fit(frames) needs the scenario too: fit(frames, scenario)")
        return data, scenario
    raise TypeError(f"fit() takes a Dataset or Frames, got {type(data).__name__}")


class Localizer:
    """Base class: settings in the constructor, ``fit`` / ``partial_fit``, results in ``*_`` attributes."""

    name: ClassVar[str] = ""

    # -------------------------------------------------------------------------- sklearn contract

    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values()
                if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self._param_names()}

    def set_params(self, **params: Any) -> Localizer:
        valid = set(self._param_names())
        for k, v in params.items():
            if k not in valid:
                raise ValueError(f"{type(self).__name__} has no setting {k!r}; settings: {sorted(valid)}")
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    # -------------------------------------------------------------------------------- fitting

    def fit(self, data: Dataset | Frames, scenario: Scenario | None = None) -> Localizer:
        """Estimate from a whole flight (replaces any earlier fit)."""
        frames, scenario = as_frames_scenario(data, scenario)
        self._reset()
        self.scenario_ = scenario
        self.frames_seen_ = frames
        self._fit(frames, scenario)
        return self

    def partial_fit(self, data: Dataset | Frames, scenario: Scenario | None = None) -> Localizer:
        """Feed more frames of the same flight; batch methods refit on all frames seen so far."""
        if not hasattr(self, "scenario_"):
            return self.fit(data, scenario)
        frames, scenario = as_frames_scenario(data, scenario if scenario is not None else self.scenario_)
        self.frames_seen_ = concat_frames(self.frames_seen_, frames)
        self._partial_fit(frames, self.scenario_)
        return self

    def _reset(self) -> None:
        for k in [k for k in vars(self) if k.endswith("_") and not k.startswith("__")]:
            delattr(self, k)

    def _fit(self, frames: Frames, scenario: Scenario) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _partial_fit(self, frames: Frames, scenario: Scenario) -> None:
        self._fit(self.frames_seen_, scenario)

    # -------------------------------------------------------------------------------- results

    def _check_fitted(self) -> None:
        if not hasattr(self, "sources_"):
            raise NotFittedError(f"{type(self).__name__} is not fitted yet: call fit() first")

    @property
    def position_(self) -> np.ndarray:
        """(3,) position of the first (strongest-evidence) source."""
        self._check_fitted()
        s = self.sources_[0]
        return np.array([s["x"], s["y"], s["z"]])

    def position_std(self, i: int = 0) -> np.ndarray:
        """(3,) standard deviation of source i's position from ``covariance_``."""
        self._check_fitted()
        c = np.asarray(self.covariance_)[4 * i:4 * i + 3, 4 * i:4 * i + 3]
        return np.sqrt(np.clip(np.diag(c), 0, None))

    def pinned_at_bounds(self, tol_m: float = 1e-3) -> list[dict[str, str]]:
        """Per source, the horizontal coordinates that sit on the scenario's bounds (within ``tol_m``), e.g.
        ``{"x": "max"}``: such a coordinate is where the search box stopped the fit, not a measurement, and its
        spread (often 0) says nothing. Empty dicts when every estimate is inside."""
        self._check_fitted()
        scenario = getattr(self, "scenario_", None)
        out: list[dict[str, str]] = []
        for s in self.sources_:
            pinned: dict[str, str] = {}
            if scenario is not None:
                for axis, key in enumerate(("x", "y")):
                    lo, hi = float(scenario.bounds_min[axis]), float(scenario.bounds_max[axis])
                    if s[key] <= lo + tol_m:
                        pinned[key] = "min"
                    elif s[key] >= hi - tol_m:
                        pinned[key] = "max"
            out.append(pinned)
        return out

    def result(self) -> dict[str, Any]:
        """JSON-able result: method, sources, background, covariance, crlb (None when unknown), and per source
        the coordinates pinned at a bound (``pinned_at_bound``, see :meth:`pinned_at_bounds`)."""
        self._check_fitted()
        crlb = getattr(self, "crlb_", None)
        out = {
            "method": self.name,
            "sources": [dict(s) for s in self.sources_],
            "pinned_at_bound": self.pinned_at_bounds(),
            "background_cps": float(self.background_),
            "covariance": np.asarray(self.covariance_, dtype=float).tolist(),
            "crlb": None if crlb is None else np.asarray(crlb, dtype=float).tolist(),
            "settings": {k: _jsonable(v) for k, v in self.get_params().items()},
        }
        extra = getattr(self, "info_", None)
        if extra:
            out["info"] = {k: _jsonable(v) for k, v in extra.items()}
        return out

    def to_estimate(self, t: float = 0.0) -> Estimate:
        """The zenoh ``estimate`` payload of the current result: per source, its 4 x 4 block of
        ``covariance_`` (and ``crlb_``) row-major, the blocks in one list, as ``radseek.topics.Estimate`` declares."""
        self._check_fitted()
        crlb = getattr(self, "crlb_", None)
        n = len(self.sources_)
        est = Estimate(t=float(t), method=self.name, sources=[dict(s) for s in self.sources_],
                       background_cps=float(self.background_), covariance=_source_blocks(self.covariance_, n),
                       crlb=None if crlb is None else _source_blocks(crlb, n))
        est.validate()
        return est


def _source_blocks(matrix: Any, n_sources: int) -> list[float]:
    """The diagonal 4 x 4 blocks of a 4M x 4M matrix, each row-major (16 numbers), one after the other."""
    k = len(ESTIMATE_STATE)
    m = np.asarray(matrix, dtype=float)
    if m.shape != (k * n_sources, k * n_sources):
        raise ValueError(f"expected a {k * n_sources} x {k * n_sources} matrix for {n_sources} source(s), "
                         f"got shape {m.shape}")
    return [v for i in range(n_sources) for v in m[k * i:k * (i + 1), k * i:k * (i + 1)].ravel().tolist()]


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, tuple | list):
        return [_jsonable(a) for a in v]
    if isinstance(v, dict):
        return {str(k): _jsonable(a) for k, a in v.items()}
    if isinstance(v, float | int | str | bool) or v is None:
        return v
    return repr(v)


def clone(localizer: Localizer) -> Localizer:
    """An unfitted localizer with the same settings (deep-copied), like sklearn.base.clone."""
    return type(localizer)(**copy.deepcopy(localizer.get_params()))


def localizer_class(name: str) -> type[Localizer]:
    if name not in LOCALIZERS:
        raise ValueError(f"unknown localizer {name!r}; choose from {', '.join(LOCALIZERS)}")
    module, cls = LOCALIZERS[name].split(":")
    return getattr(importlib.import_module(module), cls)


def make_localizer(name: str, **settings: Any) -> Localizer:
    """A localizer by registry name (``sphere``, ``pf``, ``multi-pf``, ``gp``, ``mle``) with its settings."""
    cls = localizer_class(name)
    unknown = set(settings) - set(cls._param_names())
    if unknown:
        raise ValueError(f"{name} has no setting(s) {sorted(unknown)}; settings: {sorted(cls._param_names())}")
    return cls(**settings)
