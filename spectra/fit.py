"""Fit the physical response to a measured spectrum, with forward selection over response effects.

The likelihood is Poisson on the native channels in the fit range (measured counts n_j against
mu_j = A * shape_j + B_j, the background B fixed from a measured background spectrum scaled by live time);
MIGRAD with errordef 0.5 on the negative log-likelihood, HESSE for the errors (iminuit). The deviance
2 sum[mu - n + n ln(n / mu)] per degree of freedom says how far the model is from the data's own noise.

Forward selection, as ``diagnose`` does for flight effects: start from the emulator's response (baseline
parameters, only the amplitude free); each round, every effect not yet in the model is tried (its parameters
freed, the others held at their current values, a short fit), the one that lowers the deviance most is added and
the whole model refitted; stop when the best deviance drop is below ``min_gain`` (a share of the current
deviance) or below the chi-square 99.9 % quantile for its parameter count. A best candidate above that quantile
but short of ``min_gain`` is scored again with the chosen effects refitted beside it (one full fit) before the
rule is applied: the short fit under-scores an effect whose signature the chosen ones partly carry. Discrete
effects (crystal size, K X-ray escape) are scored on a small grid.

Shape distances: ``total_variation_32`` is half the L1 distance of the normalised spectra (measured minus
background, model source part) rebinned to the 32 channels of the default scene whose lower edge is >= 60 keV;
``total_variation_native`` the same on the native channels above 60 keV.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from iminuit import Minuit
from scipy import stats

from radseek_io.spectrum_io import Spectrum
from spectra import model as M

TV_MIN_KEV = 60.0
#: a still-missing window's measured / model ratio is given only where the model expects this many counts
MIN_MODEL_COUNTS = 1.0
#: the fit starts above the X-rays near CsI's K edges (33-36 keV), where CsI(Tl)'s non-proportional light
#: yield puts the 32 keV Ba X-ray of Cs-137 at 27 keV on the RadiaCode's calibration: fitting it pulled the
#: energy offset by -4.6 keV and moved Ba-133's 81 keV peak off (checked: Ba-133 TV32 0.120 with it, 0.050 without)
FIT_MIN_KEV = 50.0


@dataclass
class Problem:
    """A measured spectrum, its background and the nuclides it shows."""

    spectrum: Spectrum
    nuclides: tuple[str, ...]
    background: Spectrum | None = None
    fit_min_keV: float = FIT_MIN_KEV
    #: where the spectrum came from (reports only)
    name: str = ""

    def __post_init__(self) -> None:
        b = self.spectrum.edges_keV()
        self.boundaries = b
        self.mask = b[:-1] >= self.fit_min_keV
        self.n = self.spectrum.counts
        if self.background is not None:
            bg = self.background.rebin(b, overflow=False) * (self.spectrum.livetime / self.background.livetime)
            self.bg = np.maximum(bg, 0.0)
        else:
            self.bg = np.zeros_like(self.n)
        first = int(np.argmax(self.mask))
        self.sub_b = b[first:]
        self.first = first
        # the last channel is the overflow: the RadiaCode adds every pulse above the top edge there (1030 counts in
        # K40.rcspg's 43,510 s, cosmic muons; the model's last channel is its top bin only). Out of the fit and of
        # the distances (net and shape both 0 there); the XML files of RC-102-001272 hold 0 counts in it.
        self.mask[-1] = False

    def shape(self, params: dict[str, float]) -> np.ndarray:
        out = np.zeros(len(self.n))
        out[self.first:] = M.native_shape(params, self.nuclides, self.sub_b)
        out[-1] = 0.0
        return out

    def net(self) -> np.ndarray:
        out = self.n - self.bg
        out[-1] = 0.0
        return out

    @property
    def rate_cps(self) -> float:
        return float(self.n.sum()) / max(self.spectrum.livetime, 1e-300)


#: per-spectrum drift of the energy law in a joint fit (sessions days apart): m_k = offset_k + gain_k m(e)
DRIFT_LIMITS = {"gain_drift": (0.9, 1.1), "offset_drift_keV": (-30.0, 30.0)}
DRIFT_START = {"gain_drift": 1.0, "offset_drift_keV": 0.0}


@dataclass
class Joint:
    """Several spectra of one unit, one response (``radseek calibrate A.xml=Cs-137 B.xml=Eu-152``).

    The negative log-likelihood is the sum over the spectra; each spectrum has its own amplitude (profiled),
    its own background and nuclides, and shares every response parameter. Two parameters are per spectrum by
    their physics: the pile-up share scales with the spectrum's rate (pileup_k = pileup_0 r_k / r_0, one
    resolving time), and with ``drift`` every spectrum after the first has its own gain and offset on top of the
    shared energy law (``gain_drift_k``, ``offset_drift_keV_k``: m_k = offset_k + gain_k m(e)), for sessions days
    apart whose device calibration moved. The first spectrum is the reference of the law.
    """

    parts: tuple[Problem, ...]
    #: True: every spectrum after the first drifts; a collection of indices (>= 1): only those spectra (a session
    #: days apart among same-day ones, e.g. K40.rcspg beside Cs-137 and Eu-152 of one day)
    drift: bool | tuple[int, ...] = False

    def __post_init__(self) -> None:
        self.parts = tuple(self.parts)
        if not self.parts:
            raise ValueError("a joint calibration needs at least one spectrum")
        if not isinstance(self.drift, bool):
            self.drift = tuple(sorted(set(int(k) for k in self.drift)))
            if any(k < 1 or k >= len(self.parts) for k in self.drift):
                raise ValueError(f"drift indices {self.drift} must name spectra after the first "
                                 f"(1..{len(self.parts) - 1})")

    def drifting(self) -> tuple[int, ...]:
        """Indices of the spectra with their own gain and offset."""
        if self.drift is True:
            return tuple(range(1, len(self.parts)))
        return tuple(self.drift) if self.drift else ()

    @property
    def nuclides(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(n for pr in self.parts for n in pr.nuclides))

    @property
    def fit_min_keV(self) -> float:
        return min(pr.fit_min_keV for pr in self.parts)

    def drift_params(self) -> tuple[str, ...]:
        return tuple(f"{name}_{k}" for k in self.drifting() for name in DRIFT_LIMITS)

    def part_params(self, params: dict[str, float], k: int) -> dict[str, float]:
        """The response parameters that spectrum ``k`` sees (its pile-up share, its drifted energy law)."""
        q = dict(params)
        if k > 0:
            q["pileup"] = min(params["pileup"] * self.parts[k].rate_cps / max(self.parts[0].rate_cps, 1e-300),
                              M.PARAMS["pileup"].hi)
        if k in self.drifting():
            g = params.get(f"gain_drift_{k}", 1.0)
            q["gain"] = params["gain"] * g
            q["offset_keV"] = params["offset_keV"] * g + params.get(f"offset_drift_keV_{k}", 0.0)
        return q


def _limits(name: str) -> tuple[float, float]:
    if name in M.PARAMS:
        return M.PARAMS[name].lo, M.PARAMS[name].hi
    return DRIFT_LIMITS[name.rsplit("_", 1)[0]]


def _with_drift_start(problem: Problem | Joint, params: dict[str, float]) -> dict[str, float]:
    """``params`` completed: a parameter it lacks (a detector file from before the parameter existed) at its
    baseline, drift parameters at no drift."""
    params = {**M.baseline_params(), **params}
    if isinstance(problem, Joint):
        for name in problem.drift_params():
            params.setdefault(name, DRIFT_START[name.rsplit("_", 1)[0]])
    return params


def _nll(mu: np.ndarray, n: np.ndarray) -> float:
    mu = np.maximum(mu, 1e-12)
    return float(np.sum(mu - n * np.log(mu)))


def deviance(mu: np.ndarray, n: np.ndarray) -> float:
    mu = np.maximum(mu, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(n > 0, n * np.log(n / mu), 0.0)
    return float(2 * np.sum(mu - n + t))


def best_amplitude(shape: np.ndarray, n: np.ndarray, bg: np.ndarray) -> float:
    """Poisson maximum-likelihood amplitude of mu = A shape + bg (a few Newton steps from the moment estimate)."""
    s = shape
    a = max((n.sum() - bg.sum()) / max(s.sum(), 1e-300), 1e-9)
    for _ in range(30):
        mu = np.maximum(a * s + bg, 1e-12)
        g = np.sum(s * (n / mu - 1))
        h = -np.sum(s * s * n / mu**2)
        if h >= 0:
            break
        step = -g / h
        a = max(a + step, a * 0.1)
        if abs(step) < 1e-9 * a:
            break
    return a


def total_variation(p: np.ndarray, q: np.ndarray) -> float:
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    return 0.5 * float(np.abs(p / p.sum() - q / q.sum()).sum())


def reference_edges() -> np.ndarray:
    """The 33 channel edges of the default scene (the board's comparator ladder)."""
    from detector_fw_sim.scene import load_scene

    return np.asarray(load_scene().channel_edges_keV, dtype=float)


def shape_distances(problem: Problem, shape: np.ndarray, edges32: np.ndarray | None = None) -> dict[str, float]:
    """total_variation_32 and total_variation_native of measured net counts against the model's source part."""
    edges32 = reference_edges() if edges32 is None else edges32
    b = problem.boundaries
    net = problem.net()
    model_sp = Spectrum(np.maximum(shape, 0), 1.0, calibration=problem.spectrum.calibration, bin_edges_kev=b)
    meas32 = _rebin_signed(net, b, edges32)
    mod32 = model_sp.rebin(edges32)
    keep32 = edges32[:-1] >= TV_MIN_KEV
    keepn = b[:-1] >= TV_MIN_KEV
    return {"total_variation_32": total_variation(np.maximum(meas32[keep32], 0), mod32[keep32]),
            "total_variation_native": total_variation(np.maximum(net[keepn], 0), shape[keepn])}


def _rebin_signed(values: np.ndarray, b: np.ndarray, edges: np.ndarray) -> np.ndarray:
    cum = np.r_[0.0, np.cumsum(values)]
    ce = np.interp(edges, b, cum)
    out = np.diff(ce)
    out[-1] = cum[-1] - ce[-2]
    return out


@dataclass
class FitResult:
    params: dict[str, float]
    errors: dict[str, float]
    free: tuple[str, ...]
    effects: tuple[str, ...]
    amplitude: float
    deviance: float
    dof: int
    expected: np.ndarray  # (n,) total expected counts (source + background)
    shape: np.ndarray  # (n,) source part, counts
    steps: list[dict] = field(default_factory=list)
    #: a joint fit: one result per spectrum (its own parameters as it sees them, amplitude, deviance, dof)
    parts: list[FitResult] = field(default_factory=list)

    @property
    def deviance_per_dof(self) -> float:
        return self.deviance / max(self.dof, 1)


def fit(problem: Problem | Joint, params: dict[str, float], effects: tuple[str, ...], maxfev: int = 4000,
        hesse: bool = True) -> FitResult:
    """Fit the continuous parameters of ``effects`` (the amplitude always), the rest held at ``params``.

    On a ``Joint`` problem the likelihood is summed over its spectra (each its own amplitude) and its drift
    parameters are free as well; the result's ``parts`` hold each spectrum's own result."""
    params = _with_drift_start(problem, params)
    free = tuple(dict.fromkeys(p for e in effects for p in M.EFFECTS[e] if p not in M.DISCRETE))
    if isinstance(problem, Joint):
        free = free + problem.drift_params()
    parts = problem.parts if isinstance(problem, Joint) else (problem,)

    def sub(q: dict[str, float], k: int) -> dict[str, float]:
        return problem.part_params(q, k) if isinstance(problem, Joint) else q

    def nll_of(x: np.ndarray) -> float:
        q = dict(params)
        q.update(zip(free, x, strict=True))
        total = 0.0
        for k, pr in enumerate(parts):
            m = pr.mask
            shape = pr.shape(sub(q, k))
            a = best_amplitude(shape[m], pr.n[m], pr.bg[m])
            total += _nll(a * shape[m] + pr.bg[m], pr.n[m])
        return total

    errors: dict[str, float] = {}
    if free:
        x0 = [params[p] for p in free]
        m = Minuit(nll_of, x0, name=free)
        m.errordef = Minuit.LIKELIHOOD
        m.limits = [_limits(p) for p in free]
        m.strategy = 1
        m.migrad(ncall=maxfev)
        if hesse and m.valid:
            try:
                m.hesse()
            except Exception:  # pragma: no cover - HESSE failing leaves MIGRAD's errors
                pass
        params.update(zip(free, (float(v) for v in m.values), strict=True))
        errors = {p: float(e) for p, e in zip(free, m.errors, strict=True)}
    results = []
    for k, pr in enumerate(parts):
        q = sub(params, k)
        mask = pr.mask
        shape = pr.shape(q)
        a = best_amplitude(shape[mask], pr.n[mask], pr.bg[mask])
        mu = a * shape + pr.bg
        dev = deviance(mu[mask], pr.n[mask])
        results.append(FitResult(q, errors, free, tuple(effects), a, dev, int(mask.sum()) - 1, mu, a * shape))
    if not isinstance(problem, Joint):
        r = results[0]
        r.dof -= len(free)
        return r
    dof = sum(r.dof for r in results) - len(free)
    first = results[0]
    return FitResult(params, errors, free, tuple(effects), first.amplitude, sum(r.deviance for r in results), dof,
                     first.expected, first.shape, parts=results)


def distances(problem: Problem | Joint, res: FitResult) -> dict:
    """``shape_distances`` of a result; for a joint fit the worst spectrum's, and each spectrum's in
    ``per_spectrum``."""
    if not isinstance(problem, Joint):
        return shape_distances(problem, res.shape)
    per = [shape_distances(pr, r.shape) for pr, r in zip(problem.parts, res.parts, strict=True)]
    return {"total_variation_32": max(d["total_variation_32"] for d in per),
            "total_variation_native": max(d["total_variation_native"] for d in per),
            "per_spectrum": [round(d["total_variation_32"], 4) for d in per]}


def _discrete_grid(effect: str, params: dict[str, float]) -> list[dict[str, float]]:
    if effect == "k_xray_escape":
        return [{"k_escape": 1.0}]
    if effect == "crystal_size":
        c = params["crystal_mm"]
        e = params["escape_scale"]
        return [{"crystal_mm": 0.8 * c}, {"crystal_mm": 1.2 * c}, {"escape_scale": 0.7 * e}, {"escape_scale": 0.5 * e},
                {"escape_scale": 1.4 * e}]
    return [{}]


def forward_select(problem: Problem | Joint, start: dict[str, float] | None = None,
                   candidates: tuple[str, ...] | None = None, min_gain: float = 0.01,
                   log=None) -> FitResult:
    """Forward selection over response effects (module docstring). ``steps`` records each round."""
    params = dict(start or M.baseline_params())
    candidates = tuple(e for e in (candidates or M.EFFECTS) if identifiable(e, problem))
    chosen: list[str] = []
    cur = fit(problem, params, (), hesse=False)
    steps = [{"added": None, "deviance": cur.deviance, "deviance_per_dof": cur.deviance_per_dof,
              **distances(problem, cur)}]
    if log:
        log(f"baseline: deviance/dof {cur.deviance_per_dof:.2f}, TV32 {_tv_text(steps[0])}")
    while True:
        trials = []
        for eff in candidates:
            if eff in chosen:
                continue
            best = None
            for disc in _discrete_grid(eff, cur.params):
                p = dict(cur.params)
                p.update({k: v for k, v in M.START.items() if k in M.EFFECTS[eff]})
                p.update(disc)
                r = fit(problem, p, (eff,), maxfev=400, hesse=False)
                if best is None or r.deviance < best.deviance:
                    best = r
            trials.append((cur.deviance - best.deviance, eff, best))  # type: ignore[union-attr]
        if not trials:
            break
        trials.sort(key=lambda t: -t[0])
        gain, eff, trial = trials[0]
        k = len([p for p in M.EFFECTS[eff] if p not in M.DISCRETE]) or 1
        need = max(min_gain * cur.deviance, stats.chi2.isf(1e-3, k))
        refit = None
        if stats.chi2.isf(1e-3, k) <= gain < need:
            # the short fit holds the chosen effects: one whose signature they partly carry is under-scored
            # (RC-102's electron_escape: 16.5 alone, 54 with the scatter shares and resolution freed beside it)
            refit = fit(problem, trial.params, (*chosen, eff), hesse=False)
            if log:
                log(f"{eff}: deviance drop {gain:.1f} alone, {cur.deviance - refit.deviance:.1f} refitted with "
                    f"the chosen effects (needs {need:.1f})")
            gain = cur.deviance - refit.deviance
        if gain < need:
            if log:
                log(f"stop: best candidate {eff} lowers the deviance by only {gain:.1f}")
            break
        chosen.append(eff)
        cur = refit if refit is not None else fit(problem, trial.params, tuple(chosen), hesse=False)
        if eff in ("crystal_size",):  # refine the discrete pair around the chosen grid point
            cur = _refine_crystal(problem, cur, tuple(chosen))
        d = distances(problem, cur)
        steps.append({"added": eff, "deviance": cur.deviance, "deviance_per_dof": cur.deviance_per_dof,
                      "deviance_drop": gain, **d})
        if log:
            log(f"+ {eff}: deviance/dof {cur.deviance_per_dof:.2f}, TV32 {_tv_text(d)}")
    final = fit(problem, cur.params, tuple(chosen), hesse=True)
    final.steps = steps
    return final


def _tv_text(d: dict) -> str:
    if "per_spectrum" in d:
        return " / ".join(f"{v:.4f}" for v in d["per_spectrum"])
    return f"{d['total_variation_32']:.4f}"


def _refine_crystal(problem: Problem | Joint, cur: FitResult, effects: tuple[str, ...]) -> FitResult:
    best = cur
    for _ in range(2):
        c, s = best.params["crystal_mm"], best.params["escape_scale"]
        for dc, ds in ((0.9, 1.0), (1.1, 1.0), (1.0, 0.85), (1.0, 1.18)):
            p = dict(best.params)
            p["crystal_mm"] = float(np.clip(c * dc, M.PARAMS["crystal_mm"].lo, M.PARAMS["crystal_mm"].hi))
            p["escape_scale"] = float(np.clip(s * ds, M.PARAMS["escape_scale"].lo, M.PARAMS["escape_scale"].hi))
            r = fit(problem, p, effects, maxfev=600, hesse=False)
            if r.deviance < best.deviance:
                best = r
    return best


#: effects that act on low-energy lines only: without a line of >= 1 % yield between the fit's lower end and
#: 150 keV their parameters are fitted to the continuum alone and trade against scatter (an aluminium absorber
#: fitted on Cs-137 alone cut Ba-133's 81 keV peak: Ba-133 TV32 0.094 against 0.050 without it)
LOW_ENERGY_EFFECTS = ("absorber", "k_xray_escape")


#: effects that need photopeaks spread over the energy range: at least ``SPREAD_MIN_GROUPS`` lines of at least
#: ``SPREAD_MIN_YIELD`` per decay, each more than ``SPREAD_MIN_GAP_KEV`` above the previous one, spanning a factor
#: ``SPREAD_MIN_RATIO`` in energy (Eu-152, Ba-133, Th-232 or Cs-137 with Co-60; not Cs-137 or Co-60 alone)
#: electron_escape too: its signature is how the peak-to-total ratio falls with energy, which one line cannot tell
#: from the scatter shares
SPREAD_EFFECTS = ("energy_nonlinearity", "resolution_curvature", "electron_escape")
SPREAD_MIN_YIELD, SPREAD_MIN_GAP_KEV, SPREAD_MIN_GROUPS, SPREAD_MIN_RATIO = 0.02, 100.0, 3, 3.0


def line_groups(problem: Problem | Joint, min_yield: float = SPREAD_MIN_YIELD,
                min_gap_keV: float = SPREAD_MIN_GAP_KEV) -> list[float]:
    """Energies of the problem's lines of at least ``min_yield`` in the fit range, each more than ``min_gap_keV``
    above the previous one kept."""
    from radseek.photon_lines import source_lines

    kept: list[float] = []
    for e in sorted(e for n in problem.nuclides for e, y in source_lines(n)
                    if y >= min_yield and problem.fit_min_keV <= e <= 3000.0):
        if not kept or e - kept[-1] > min_gap_keV:
            kept.append(e)
    return kept


def identifiable(effect: str, problem: Problem | Joint) -> bool:
    if effect == "coincidence_summing":  # only a cascade the library's yields force together (Co-60)
        return bool(M.cascade_pairs(problem.nuclides))
    if effect in SPREAD_EFFECTS:
        g = line_groups(problem)
        return len(g) >= SPREAD_MIN_GROUPS and g[-1] >= SPREAD_MIN_RATIO * g[0]
    if effect not in LOW_ENERGY_EFFECTS:
        return True
    from radseek.photon_lines import source_lines

    return any(problem.fit_min_keV <= e <= 150.0 and y >= 0.01 for n in problem.nuclides for e, y in source_lines(n))


def _poisson_amplitudes(n: np.ndarray, bg: np.ndarray, shapes: list[np.ndarray], iterations: int = 3000
                        ) -> tuple[np.ndarray, float]:
    """Maximum-likelihood amplitudes (>= 0) of mu = sum_i a_i s_i + bg for Poisson counts n (EM: every step raises
    the likelihood), and the deviance at them."""
    net = max(float(n.sum() - bg.sum()), 1.0)
    a = np.array([net / max(float(s.sum()), 1e-300) / len(shapes) for s in shapes])
    sums = np.array([max(float(s.sum()), 1e-300) for s in shapes])
    for _ in range(iterations):
        mu = sum(ai * s for ai, s in zip(a, shapes, strict=True)) + bg
        r = n / np.maximum(mu, 1e-300)
        a = a * np.array([(r * s).sum() for s in shapes]) / sums
    mu = np.maximum(sum(ai * s for ai, s in zip(a, shapes, strict=True)) + bg, 1e-300)
    dev = float(2 * (mu - n + np.where(n > 0, n * np.log(np.maximum(n, 1e-300) / mu), 0.0)).sum())
    return a, dev


def fit_with_component(problem: Problem, params: dict[str, float], source: str,
                       source_params: dict[str, float] | None = None) -> dict[str, float]:
    """A held response and one more source component (``source``, a ``spectra.model`` source name such as
    ``brems:U-nat`` or ``backscatter:Ra-226``, evaluated at ``source_params``), each with its own amplitude (the
    rest held): TV32 with it, the component's share of the counts, its photons per photon of the problem's lines
    (with the Poisson error from the Fisher information) and the deviance it removes."""
    lines_shape = problem.shape(params)
    extra = Problem(problem.spectrum, (source,), problem.background, problem.fit_min_keV).shape(
        source_params if source_params is not None else params)
    m = problem.mask
    n, bg, s1, s2 = problem.n[m], problem.bg[m], lines_shape[m], extra[m]
    (a0,), dev0 = _poisson_amplitudes(n, bg, [s1])
    a, dev = _poisson_amplitudes(n, bg, [s1, s2])
    mu = np.maximum(a[0] * s1 + a[1] * s2 + bg, 1e-300)
    fisher = np.array([[(s1 * s1 / mu).sum(), (s1 * s2 / mu).sum()], [(s1 * s2 / mu).sum(), (s2 * s2 / mu).sum()]])
    cov = np.linalg.inv(fisher)
    photons = sum(y for nuc in problem.nuclides for _, y in M.source_lines(nuc))  # the component is 1 photon
    ratio = a[1] / max(a[0], 1e-300)
    # delta method for a1 / a0
    grad = np.array([-ratio / max(a[0], 1e-300), 1 / max(a[0], 1e-300)])
    ratio_err = math.sqrt(max(float(grad @ cov @ grad), 0.0))
    return {"total_variation_32": shape_distances(problem, a[0] * lines_shape + a[1] * extra)["total_variation_32"],
            "total_variation_32_without": shape_distances(problem, lines_shape)["total_variation_32"],
            "share": float(a[1] * s2.sum() / (a[0] * s1.sum() + a[1] * s2.sum())),
            "per_photon": float(ratio / photons), "per_photon_error": ratio_err / photons,
            "deviance_drop": dev0 - dev}


def evaluate(problem: Problem | Joint, params: dict[str, float]) -> FitResult:
    """A saved response on another spectrum: only the amplitude is fitted."""
    return fit(problem, params, (), hesse=False)


def residual_regions(problem: Problem, res: FitResult, n_regions: int = 3) -> list[dict]:
    """Where the fitted model is still wrong: energy windows with the largest summed deviance contributions."""
    mask = problem.mask
    n, mu = problem.n, np.maximum(res.expected, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = 2 * (mu - n + np.where(n > 0, n * np.log(n / mu), 0.0))
    d[~mask] = 0
    b = problem.boundaries
    windows = []
    lo_e = max(problem.fit_min_keV, b[0])
    edges = np.geomspace(lo_e, b[-1], 25)
    centre = 0.5 * (b[1:] + b[:-1])
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = (centre >= lo) & (centre < hi) & mask
        if sel.sum() == 0:
            continue
        excess = float((n[sel] - mu[sel]).sum())
        model = float(mu[sel].sum())
        windows.append({"from_keV": round(float(lo), 1), "to_keV": round(float(hi), 1),
                        "deviance": round(float(d[sel].sum()), 1), "channels": int(sel.sum()),
                        "measured_minus_model": round(excess, 1), "model_counts": round(model, 2),
                        # a ratio to a model that expects (almost) nothing there is no number: None, and the
                        # counts say it (an emission or a background the model lacks)
                        "relative": round(excess / model, 4) if model >= MIN_MODEL_COUNTS else None})
    windows.sort(key=lambda w: -w["deviance"])
    return windows[:n_regions]


#: lines of at least this many photons per decay get a per-line check (``line_checks``)
LINE_MIN_YIELD = 0.05


def line_checks(problem: Problem, params: dict[str, float], min_yield: float = LINE_MIN_YIELD) -> list[dict]:
    """Per photopeak: how far the measured peak sits from the model's and how much wider or narrower it is.

    Lines of at least ``min_yield`` photons per decay at or above the fit's lower end are grouped when closer than one
    model FWHM (a blend is one peak). In a window of one FWHM either side of the group the model (all other
    parameters as given) is refitted with two local parameters only: a shift of the file energy (keV) and a
    factor on the FWHM, plus the amplitude (Poisson likelihood, MIGRAD/HESSE). A shift that grows toward low
    energies is CsI(Tl)'s non-proportional light yield, which one Cs-137 photopeak cannot show; a width factor
    away from 1 says the resolution law does not hold at that energy. Errors are HESSE's.
    """
    from radseek.photon_lines import source_lines

    def fw(e: float) -> float:  # model FWHM in file energy
        return float(params["gain"] * M.fwhm(params, e))

    lines = sorted((e, y) for n in problem.nuclides for e, y in source_lines(n)
                   if y >= min_yield and e * params["gain"] >= problem.fit_min_keV)
    groups: list[list[tuple[float, float]]] = []
    for e, y in lines:
        if groups and e - groups[-1][-1][0] < fw(e):
            groups[-1].append((e, y))
        else:
            groups.append([(e, y)])
    b = problem.boundaries
    centre = 0.5 * (b[1:] + b[:-1])
    out = []
    for g in groups:
        lo = float(M.file_energy(params, g[0][0])) - fw(g[0][0])
        hi = float(M.file_energy(params, g[-1][0])) + fw(g[-1][0])
        sel = (centre >= lo) & (centre < hi) & problem.mask
        if sel.sum() < 4:
            continue
        main_e = max(g, key=lambda ey: ey[1])[0]
        shift, shift_err, width, width_err = _local_peak_fit(problem, params, np.flatnonzero(sel), 0.3 * (hi - lo))
        out.append({"line_keV": round(main_e, 2), "lines_keV": [round(e, 2) for e, _ in g],
                    "window_keV": [round(lo, 1), round(hi, 1)],
                    "shift_keV": round(shift, 2), "shift_error_keV": float(f"{shift_err:.2g}"),
                    "shift_relative": round(shift / float(M.file_energy(params, main_e)), 4),
                    "fwhm_ratio": round(width, 3), "fwhm_ratio_error": float(f"{width_err:.2g}")})
    return out


def _local_peak_fit(problem: Problem, params: dict[str, float], idx: np.ndarray, max_shift: float
                    ) -> tuple[float, float, float, float]:
    """(shift keV, error, FWHM factor, error) of the model in channels ``idx``, amplitude free, the rest held."""
    sub_b = problem.boundaries[idx[0]:idx[-1] + 2]
    n, bg = problem.n[idx], problem.bg[idx]

    def nll(shift: float, width: float) -> float:
        q = dict(params, offset_keV=params["offset_keV"] + shift, fwhm_at_662=params["fwhm_at_662"] * width)
        shape = M.native_shape(q, problem.nuclides, sub_b)
        return _nll(best_amplitude(shape, n, bg) * shape + bg, n)

    m = Minuit(nll, shift=0.0, width=1.0)
    m.errordef = Minuit.LIKELIHOOD
    m.limits = [(-max_shift, max_shift), (0.3, 3.0)]
    m.migrad(ncall=300)
    m.hesse()
    return float(m.values["shift"]), float(m.errors["shift"]), float(m.values["width"]), float(m.errors["width"])


def chi2_pvalue(dev: float, dof: int) -> float:
    return float(stats.chi2.sf(dev, max(dof, 1))) if math.isfinite(dev) else float("nan")


def fit_background_scale(problem: Problem, params: dict[str, float]) -> dict:
    """The saved response (held) with the source amplitude and a free scale on the background spectrum.

    For a spectrum whose background was not measured with it (another room, another day, or a stand-in from the
    same device model), mu = A * shape + beta * B with beta free (Poisson likelihood, MIGRAD/HESSE); the shape
    distances are then taken on n - beta * B. On a spectrum with its own background beta should come out near 1.
    """
    import copy

    shape = problem.shape(params)
    m, n, bg = problem.mask, problem.n, problem.bg
    if bg[m].sum() <= 0:
        return {"scale": None, "why": "no background spectrum to scale"}

    def nll(a: float, beta: float) -> float:
        return _nll(a * shape[m] + beta * bg[m], n[m])

    a0 = best_amplitude(shape[m], n[m], bg[m])
    mi = Minuit(nll, a=a0, beta=1.0)
    mi.errordef = Minuit.LIKELIHOOD
    mi.limits = [(0.0, None), (0.0, None)]
    mi.migrad(ncall=2000)
    mi.hesse()
    a, beta = float(mi.values["a"]), float(mi.values["beta"])
    scaled = copy.copy(problem)
    scaled.bg = beta * bg
    mu = a * shape + beta * bg
    d = shape_distances(scaled, a * shape)
    return {"scale": round(beta, 4), "scale_error": float(f"{float(mi.errors['beta']):.2g}"),
            "deviance_per_dof": round(deviance(mu[m], n[m]) / max(int(m.sum()) - 2, 1), 4),
            "total_variation_32": round(d["total_variation_32"], 4),
            "total_variation_native": round(d["total_variation_native"], 4)}
