"""Scene descriptions for the detector emulator: sources, background, walls, detector, effects.

A scene is a TOML or JSON file (``detector_fw_sim/scenes/*.toml``) validated by pydantic; an error
names the file, the field (``sources[0].cps_at_1m``) and the bad value. ``load_scene()`` with no
path gives the embedded default: one Cs-137 source of 1600 cps at 1 m, 30 cps background.

Every effect of the dataset vocabulary (``radseek.dataset.EFFECTS``) has a table under
``[effects.<name>]`` with ``enabled`` and its parameters; ``Scene.with_effect`` switches one on.
``Scene.scenario()`` is what the operator knows (no sources); ``Scene.truth()`` is the truth.json
content, with the effect names and parameter keys of shared/spec/dataset-format.md.
"""

from __future__ import annotations

import json
import tomllib
from functools import cached_property
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from detector_fw_sim import response, xcom
from detector_fw_sim.ladder import REFERENCE_EDGES_KEV, ComparatorLadder
from radseek.dataset import EFFECTS, Scenario, Wall
from radseek.truth import Truth, TruthSource
from radseek_io.dataset import MAX_COORD_M, MAX_EXTENT_M, MAX_SOURCES, MAX_WALLS

SCENES_DIR = Path(__file__).resolve().parent / "scenes"
DEFAULT_SCENE = SCENES_DIR / "default.toml"

#: Wall materials beyond pydecay's table: name -> (library material, density g/cm^3, void fraction).
#: A hollow cinder block: lightweight aggregate concrete (~1.4 g/cm^3 solid) with ~50 % voids
#: (5.5 /m at 662 keV); scenes may set density_g_cm3 and void_fraction per wall.
MATERIAL_ALIASES: dict[str, tuple[str, float, float]] = {
    "cinder block": ("concrete", 1.4, 0.5),
    "cinder_block": ("concrete", 1.4, 0.5),
    "brick": ("concrete", 1.8, 0.0),
    "steel": ("iron", 7.87, 0.0),
}


class SceneError(ValueError):
    """A scene file or parameter that breaks the schema; the message names file, field and value."""


class _Model(BaseModel):
    # NaN and inf are refused everywhere: a NaN position or bound silently poisons every simulated frame
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


Vec3 = tuple[float, float, float]
Vec2 = tuple[float, float]


class SourceSpec(_Model):
    nuclide: str = "Cs-137"
    position: Vec3
    cps_at_1m: float | None = Field(default=None, gt=0)
    activity_MBq: float | None = Field(default=None, gt=0)

    @field_validator("nuclide")
    @classmethod
    def _known_nuclide(cls, v: str) -> str:
        response.gamma_lines(v)  # raises ValueError naming the nuclide
        return v

    @model_validator(mode="after")
    def _one_strength(self) -> SourceSpec:
        if (self.cps_at_1m is None) == (self.activity_MBq is None):
            raise ValueError("give exactly one of cps_at_1m or activity_MBq")
        return self


class BackgroundSpec(_Model):
    cps: float = Field(default=30.0, ge=0)
    #: what the operator believes (scenario.json); None = the truth
    operator_estimate_cps: float | None = Field(default=None, ge=0)
    #: share of background line photons per terrestrial nuclide (K, U and Th series)
    nuclides: dict[str, float] = Field(default_factory=lambda: {"K-40": 0.45, "Bi-214": 0.3, "Tl-208": 0.25})
    #: photons down-scattered in soil and air per unscattered line photon (flat in log E, 30 keV..E)
    scatter_ratio: float = Field(default=1.0, ge=0)

    @field_validator("nuclides")
    @classmethod
    def _nuclides(cls, v: dict[str, float]) -> dict[str, float]:
        if not v:
            raise ValueError("needs at least one nuclide")
        for name, share in v.items():
            response.gamma_lines(name)
            if share < 0:
                raise ValueError(f"share of {name} must be >= 0, got {share}")
        return v


class WallSpec(_Model):
    start: Vec2
    end: Vec2
    thickness: float = Field(gt=0)
    height: float = Field(default=3.0, gt=0)
    material: str = "concrete"
    density_g_cm3: float | None = Field(default=None, gt=0)
    void_fraction: float | None = Field(default=None, ge=0, lt=1)

    @field_validator("material")
    @classmethod
    def _known_material(cls, v: str) -> str:
        if v.lower() not in MATERIAL_ALIASES and v.lower() not in xcom.material_names():
            known = sorted(set(xcom.material_names()) | set(MATERIAL_ALIASES))
            raise ValueError(f"unknown material {v!r}; known: {', '.join(known)}")
        return v

    @model_validator(mode="after")
    def _has_length(self) -> WallSpec:
        if self.start == self.end:
            raise ValueError(f"start and end are the same point {list(self.start)} (a zero-length wall)")
        if max(abs(v) for v in (*self.start, *self.end)) > MAX_COORD_M:
            raise ValueError(f"coordinates beyond +-{MAX_COORD_M:g} m of the local origin (metres expected)")
        return self

    def mu_per_m(self, E_keV: float) -> float:
        name = self.material.lower()
        base, rho, void = MATERIAL_ALIASES.get(name, (name, None, 0.0))
        rho = self.density_g_cm3 if self.density_g_cm3 is not None else rho
        void = self.void_fraction if self.void_fraction is not None else void
        return response.mu_per_m(base, E_keV, rho, void)

    def to_wall(self) -> Wall:
        return Wall(tuple(self.start), tuple(self.end), self.thickness, self.height, self.material)  # type: ignore[arg-type]


class BoundsSpec(_Model):
    min: Vec3 = (0.0, 0.0, 0.0)
    max: Vec3 = (10.0, 8.0, 0.5)

    @model_validator(mode="after")
    def _ordered(self) -> BoundsSpec:
        if any(hi < lo for lo, hi in zip(self.min, self.max, strict=True)):
            raise ValueError("max must be >= min on every axis")
        if max(abs(v) for v in (*self.min, *self.max)) > MAX_COORD_M:
            raise ValueError(f"coordinates beyond +-{MAX_COORD_M:g} m of the local origin (metres expected)")
        if any(hi - lo > MAX_EXTENT_M for lo, hi in zip(self.min, self.max, strict=True)):
            raise ValueError(f"bounds span more than {MAX_EXTENT_M:g} m on an axis (metres expected)")
        return self


class LadderSpec(_Model):
    resistors_ohm: list[float] = Field(min_length=33, max_length=33)
    v_ref_V: float = Field(default=3.3, gt=0)
    gain_mV_per_keV: float = Field(default=1.1, gt=0)


class DetectorSpec(_Model):
    #: 33 ascending edges (keV); ignored when ``ladder`` is given
    channel_edges_keV: list[float] = Field(default_factory=lambda: list(REFERENCE_EDGES_KEV))
    ladder: LadderSpec | None = None
    #: energy resolution FWHM / E at 662 keV, scaling as 1/sqrt(E)
    fwhm_at_662: float = Field(default=0.07, gt=0, lt=1)
    crystal_diameter_mm: float = Field(default=10.0, gt=0)
    crystal_length_mm: float = Field(default=10.0, gt=0)
    #: share of photons reaching the crystal after back-scattering in the surroundings
    backscatter_fraction: float = Field(default=0.05, ge=0, lt=1)
    axis: str = "body +x"
    #: response effects of a calibrated crystal (response.ResponseEffects); the defaults are the bare crystal
    fwhm_exponent: float = Field(default=0.5, ge=0, le=1)
    scatter_side: float = Field(default=0.0, ge=0, lt=1)
    scatter_multiple: float = Field(default=0.0, ge=0, lt=1)
    absorber_g_cm2: float = Field(default=0.0, ge=0)
    k_escape: bool = False
    escape_scale: float = Field(default=1.0, gt=0)
    #: smallest angle of the side scatter (deg; ``radseek calibrate``'s side_scatter_angle effect)
    side_scatter_min_deg: float = Field(default=response.SIDE_SCATTER_DEG[0], ge=0, le=100)
    #: electrons leaving the crystal: mean projected / CSDA range (``radseek calibrate``'s electron_escape effect)
    electron_range_factor: float = Field(default=0.0, ge=0, le=1)
    #: a calibrated detector file (``radseek calibrate --out``, radseek_io.detector_file); its physical parameters
    #: fill the fields above that the scene does not set. ``detector = "rc102.json"`` is short for this.
    file: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _from_file(cls, data: Any) -> Any:
        if isinstance(data, str):
            data = {"file": data}
        if isinstance(data, dict) and data.get("file"):
            from radseek_io.detector_file import read_detector_file

            path = Path(data["file"])
            if not path.exists() and (SCENES_DIR / path).exists():
                path = SCENES_DIR / path
            p = read_detector_file(path).parameters  # DetectorFileError (a ValueError) names file and field
            fill = {"fwhm_at_662": p["fwhm_at_662"], "crystal_diameter_mm": p["crystal_mm"],
                    "crystal_length_mm": p["crystal_mm"], "backscatter_fraction": p["backscatter_fraction"],
                    "fwhm_exponent": p["fwhm_exponent"], "scatter_side": p["scatter_side"],
                    "scatter_multiple": p["scatter_multiple"], "absorber_g_cm2": p["absorber_g_cm2"],
                    "k_escape": p["k_escape"] >= 0.5, "escape_scale": p["escape_scale"]}
            for name in ("side_scatter_min_deg", "electron_range_factor"):  # older files lack them
                if name in p:
                    fill[name] = p[name]
            data = {**fill, **data}
        return data

    @field_validator("channel_edges_keV")
    @classmethod
    def _edges(cls, v: list[float]) -> list[float]:
        if len(v) != 33:
            raise ValueError(f"needs 33 edges (32 channels), got {len(v)}")
        if v[0] <= 0 or any(b <= a for a, b in zip(v, v[1:], strict=False)):
            raise ValueError("edges must be positive and strictly ascending")
        return v

    def comparator_ladder(self) -> ComparatorLadder:
        if self.ladder is not None:
            return ComparatorLadder(tuple(self.ladder.resistors_ohm), self.ladder.v_ref_V, self.ladder.gain_mV_per_keV)
        return ComparatorLadder.from_edges(np.asarray(self.channel_edges_keV))

    @property
    def crystal(self) -> response.Crystal:
        eff = response.ResponseEffects(fwhm_exponent=self.fwhm_exponent, k_escape=self.k_escape,
                                       absorber_g_cm2=self.absorber_g_cm2, scatter_side=self.scatter_side,
                                       scatter_multiple=self.scatter_multiple, escape_scale=self.escape_scale,
                                       side_scatter_min_deg=self.side_scatter_min_deg,
                                       electron_range_factor=self.electron_range_factor)
        return response.Crystal(self.crystal_diameter_mm, self.crystal_length_mm,
                                None if eff == response.ResponseEffects() else eff)


# ------------------------------------------------------------------------------------ effects


class DeadTime(_Model):
    enabled: bool = False
    tau_s: float = Field(default=1.2e-5, ge=0)


class WallAttenuation(_Model):
    enabled: bool = False
    #: override of every wall's coefficient at the main line (1/m); None = from each wall's material
    mu_per_m: float | None = Field(default=None, ge=0)


class Anisotropy(_Model):
    enabled: bool = False
    fraction: float = Field(default=0.5, ge=0, le=1)
    half_angle_deg: float = Field(default=30.0, ge=0, le=180)
    edge_deg: float = Field(default=4.0, gt=0)


class AirAttenuation(_Model):
    enabled: bool = False
    #: override at the main line (1/m); None = NIST XCOM air at each line energy
    mu_per_m: float | None = Field(default=None, ge=0)


class SecondSource(_Model):
    enabled: bool = False
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    cps_at_1m: float = Field(default=1000.0, gt=0)


class BackgroundGradient(_Model):
    enabled: bool = False
    gx: float = 0.0
    gy: float = 0.0


class GainDrift(_Model):
    enabled: bool = False
    percent_per_min: float = 1.0


class PoseDrift(_Model):
    enabled: bool = False
    vx: float = 0.002
    vy: float = 0.0


class EffectsSpec(_Model):
    dead_time: DeadTime = DeadTime()
    wall_attenuation: WallAttenuation = WallAttenuation()
    anisotropy: Anisotropy = Anisotropy()
    air_attenuation: AirAttenuation = AirAttenuation()
    second_source: SecondSource = SecondSource()
    background_gradient: BackgroundGradient = BackgroundGradient()
    gain_drift: GainDrift = GainDrift()
    pose_drift: PoseDrift = PoseDrift()


assert set(EffectsSpec.model_fields) == set(EFFECTS), "every dataset-spec effect needs a scene table"


# ------------------------------------------------------------------------------------ scene


#: bytes of a scene file at most (1000 walls and 16 sources fit in well under this)
MAX_SCENE_BYTES = 4_000_000


class Scene(_Model):
    name: str = "scene"
    description: str = ""
    sources: list[SourceSpec] = Field(min_length=1, max_length=MAX_SOURCES)
    background: BackgroundSpec = BackgroundSpec()
    walls: list[WallSpec] = Field(default_factory=list, max_length=MAX_WALLS)
    bounds: BoundsSpec = BoundsSpec()
    detector: DetectorSpec = DetectorSpec()
    effects: EffectsSpec = EffectsSpec()
    kind: Literal["indoor", "outdoor"] = "indoor"

    @model_validator(mode="after")
    def _same_nuclide(self) -> Scene:
        if len({s.nuclide for s in self.sources}) > 1:
            raise ValueError("all sources must be the same nuclide (the dataset format has one nuclide per scene)")
        return self

    @model_validator(mode="after")
    def _sources_inside_bounds(self) -> Scene:
        """The bounds are where the sources are known to be (dataset-format.md): a source outside them (in
        x or y) makes every estimate pin at a bound."""
        lo, hi = self.bounds.min, self.bounds.max
        where = [(f"sources[{i}].position", s.position[:2]) for i, s in enumerate(self.sources)]
        if self.effects.second_source.enabled:
            where.append(("effects.second_source", (self.effects.second_source.x, self.effects.second_source.y)))
        for name, (x, y) in where:
            if not (lo[0] <= x <= hi[0] and lo[1] <= y <= hi[1]):
                raise ValueError(f"{name} ({x}, {y}) is outside bounds x {lo[0]}..{hi[0]}, y {lo[1]}..{hi[1]}")
        return self

    # -- derived quantities
    @property
    def nuclide(self) -> str:
        return self.sources[0].nuclide

    @cached_property
    def channel_edges_keV(self) -> np.ndarray:
        return self.detector.comparator_ladder().edges_keV()

    def source_cps_at_1m(self, i: int) -> float:
        """cps_at_1m of source i, converting activity with the crystal's efficiency (response module)."""
        s = self.sources[i]
        if s.cps_at_1m is not None:
            return float(s.cps_at_1m)
        d = self.detector
        return response.cps_at_1m_from_activity(s.activity_MBq or 0.0, s.nuclide, d.crystal, d.fwhm_at_662,
                                                d.backscatter_fraction, self.channel_edges_keV)

    def main_line_keV(self) -> float:
        return response.main_line_keV(self.nuclide)

    def wall_mu_per_m(self, E_keV: float) -> np.ndarray:
        """(W,) coefficient of each wall at E_keV; the effect's mu_per_m override scales all walls to it
        at the main line (so the energy dependence of the material is kept)."""
        mus = np.array([w.mu_per_m(E_keV) for w in self.walls])
        override = self.effects.wall_attenuation.mu_per_m
        if override is not None and len(mus):
            main = np.array([w.mu_per_m(self.main_line_keV()) for w in self.walls])
            mus = override * mus / main
        return mus

    def air_mu_per_m(self, E_keV: float) -> float:
        mu = response.mu_per_m("air", E_keV)
        override = self.effects.air_attenuation.mu_per_m
        if override is not None:
            mu = override * mu / response.mu_per_m("air", self.main_line_keV())
        return mu

    # -- views
    def with_effect(self, name: str, **params: Any) -> Scene:
        """A copy with effect ``name`` switched on and ``params`` set (validated like a file)."""
        if name not in EFFECTS:
            raise SceneError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        data = self.model_dump()
        data["effects"][name].update({"enabled": True, **params})
        return validate_scene(data, f"with_effect({name!r})")

    def without_effects(self) -> Scene:
        data = self.model_dump()
        for name in EFFECTS:
            data["effects"][name]["enabled"] = False
        return validate_scene(data, "without_effects()")

    def enabled_effects(self) -> list[str]:
        return [n for n in EFFECTS if getattr(self.effects, n).enabled]

    def scenario(self, background_cps: float | None = None) -> Scenario:
        """The operator's view (scenario.json): instrument, walls, bounds; never the sources."""
        bg = background_cps
        if bg is None:
            bg = self.background.operator_estimate_cps
        if bg is None:
            bg = self.background.cps
        return Scenario(
            channel_edges_keV=self.channel_edges_keV.copy(),
            background_cps=round(float(bg), 2),
            source_z=float(self.sources[0].position[2]),
            bounds_min=np.array(self.bounds.min, dtype=float),
            bounds_max=np.array(self.bounds.max, dtype=float),
            walls=tuple(w.to_wall() for w in self.walls),
            nuclide=self.nuclide,
            axis=self.detector.axis,
            # a scene flown through air tells the operator so, with the library's (NIST XCOM) dry air at the
            # main line: what an operator can look up, not the scene's own value (the effect may override it)
            air_mu_per_m=round(response.mu_per_m("air", self.main_line_keV()), 6)
            if self.effects.air_attenuation.enabled else 0.0,
        )

    def truth(self) -> Truth:
        """truth.json: sources with their cps_at_1m and every enabled effect by its dataset-spec name."""
        sources = tuple(
            TruthSource(*map(float, s.position), round(self.source_cps_at_1m(i), 3), s.nuclide)
            for i, s in enumerate(self.sources)
        )
        e = self.effects
        effects: dict[str, dict[str, float]] = {}
        main = self.main_line_keV()
        if e.dead_time.enabled:
            effects["dead_time"] = {"tau_s": e.dead_time.tau_s}
        if e.wall_attenuation.enabled:
            mus = self.wall_mu_per_m(main)
            effects["wall_attenuation"] = {"mu_per_m": round(float(np.mean(mus)) if len(mus) else 0.0, 4)}
        if e.anisotropy.enabled:
            a = e.anisotropy
            effects["anisotropy"] = {"fraction": a.fraction, "half_angle_deg": a.half_angle_deg, "edge_deg": a.edge_deg}
        if e.air_attenuation.enabled:
            effects["air_attenuation"] = {"mu_per_m": round(self.air_mu_per_m(main), 6)}
        if e.second_source.enabled:
            s2 = e.second_source
            effects["second_source"] = {"x": s2.x, "y": s2.y, "z": s2.z, "cps_at_1m": s2.cps_at_1m}
        if e.background_gradient.enabled:
            effects["background_gradient"] = {"gx": e.background_gradient.gx, "gy": e.background_gradient.gy}
        if e.gain_drift.enabled:
            effects["gain_drift"] = {"percent_per_min": e.gain_drift.percent_per_min}
        if e.pose_drift.enabled:
            effects["pose_drift"] = {"vx": e.pose_drift.vx, "vy": e.pose_drift.vy}
        return Truth(sources, float(self.background.cps), effects)


# ------------------------------------------------------------------------------------ loading


def _format_loc(loc: tuple[Any, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif str(part).startswith(("function-", "tuple[", "list[")):
            continue
        else:
            out += ("." if out else "") + str(part)
    return out or "<root>"


def validate_scene(data: Any, origin: str = "<scene>") -> Scene:
    """Validate a parsed scene; raises SceneError naming origin, field and value."""
    if not isinstance(data, dict):
        raise SceneError(f"{origin}: a scene must be a table/object, got {type(data).__name__}")
    try:
        return Scene.model_validate(data)
    except ValidationError as exc:
        lines = []
        for err in exc.errors():
            msg = err["msg"].removeprefix("Value error, ")
            value = err.get("input")
            text = repr(value)
            text = text if len(text) <= 80 else f"{text[:60]}... ({len(text)} characters)"
            shown = "" if err["type"] == "missing" or err["type"] == "too_long" else f" (got {text})"
            lines.append(f"field '{_format_loc(err['loc'])}': {msg}{shown}")
        raise SceneError(f"{origin}: " + "; ".join(lines)) from None


def load_scene(path: str | Path | None = None) -> Scene:
    """Read a TOML or JSON scene; ``None`` gives the embedded default (one Cs-137 source).

    A bare name (``"lattice-wall"``) is looked up among the bundled scenes.
    """
    if path is None:
        path = DEFAULT_SCENE
    p = Path(path)
    if not p.exists() and (SCENES_DIR / f"{p.name}.toml").exists() and p.suffix == "":
        p = SCENES_DIR / f"{p.name}.toml"
    try:
        if p.stat().st_size > MAX_SCENE_BYTES:
            raise SceneError(f"{p}: {p.stat().st_size} bytes; a scene file is at most {MAX_SCENE_BYTES} bytes")
        text = p.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        bundled = ", ".join(sorted(q.stem for q in SCENES_DIR.glob("*.toml")))
        raise SceneError(f"{p}: scene file not found (bundled scenes: {bundled})") from None
    except UnicodeDecodeError as exc:
        raise SceneError(f"{p}: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise SceneError(f"{p}: cannot be read: {exc.strerror or exc}") from None
    kind = "JSON" if p.suffix.lower() == ".json" else "TOML"
    try:
        data = json.loads(text) if kind == "JSON" else tomllib.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise SceneError(f"{p}: not valid {kind}: {exc}") from None
    except RecursionError:
        raise SceneError(f"{p}: not valid {kind}: nested too deeply") from None
    if not isinstance(data, dict):
        raise SceneError(f"{p}: a scene must be a table/object, got {type(data).__name__}")
    data.setdefault("name", p.stem)
    return validate_scene(data, str(p))


def bundled_scenes() -> list[str]:
    return sorted(q.stem for q in SCENES_DIR.glob("*.toml"))

