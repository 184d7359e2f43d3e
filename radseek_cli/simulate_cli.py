"""``radseek simulate-dataset``: write a simulated flight (frames.csv, scenario.json, truth.json).

With no options it flies the built-in lattice through the default scene (one Cs-137 source) into
``./simulated-dataset``. ``--effect NAME[:key=value,...]`` switches on a dataset-spec effect.
A non-empty ``--out`` is refused unless ``--force`` (which removes the previous dataset files there
first, truth before frames; other files are kept); ``truth.json`` is written last, atomically.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from detector_fw_sim.flight_paths import BUILTIN_PATHS, FlightPathError
from detector_fw_sim.scene import SceneError, bundled_scenes, load_scene
from detector_fw_sim.simulate import simulate_flight
from radseek.dataset import EFFECTS
from radseek_io.dataset import write_dataset
from radseek_io.outdir import OutputDirError, atomic_write_json, prepare_output

#: what simulate-dataset writes under --out, truth first: --force removes them in this order
SIMULATE_OUTPUTS = ("truth.json", "frames.csv", "frames_flagged.csv", "scenario.json")


def _parse_effect(text: str) -> tuple[str, dict[str, float]]:
    name, _, rest = text.partition(":")
    params: dict[str, float] = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise SceneError(f"--effect {text!r}: parameter {item!r} must be key=value")
        try:
            params[key.strip()] = float(value)
        except ValueError:
            raise SceneError(f"--effect {text!r}: value of {key.strip()!r} must be a number, got {value!r}") from None
    return name.strip(), params


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="radseek simulate-dataset", description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=None,
                   help=f"scene TOML/JSON file or bundled name ({', '.join(bundled_scenes())}); default: default")
    p.add_argument("--path", default="lattice",
                   help=f"flight path: {', '.join(BUILTIN_PATHS)} or a CSV with x,y,z,yaw,dwell_s (default lattice)")
    p.add_argument("--out", default="runs/simulated-dataset",
                   help="output dataset directory, must be empty unless --force (default runs/simulated-dataset)")
    p.add_argument("--force", action="store_true",
                   help="use a non-empty --out: remove its previous dataset files first (other files are kept)")
    p.add_argument("--seed", type=int, default=0, help="random seed: same seed, same dataset (default 0)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:k=v,...]",
                   help=f"switch on an effect ({', '.join(EFFECTS)}), e.g. --effect dead_time:tau_s=2e-5")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        out = prepare_output(Path(args.out), force=args.force, outputs=SIMULATE_OUTPUTS)
    except OutputDirError as exc:
        print(f"radseek simulate-dataset: {exc}", file=sys.stderr)
        return 2
    try:
        scene = load_scene(args.scene)
        for text in args.effect:
            name, params = _parse_effect(text)
            scene = scene.with_effect(name, **params)
        ds = simulate_flight(scene, args.path, seed=args.seed)
    except (SceneError, FlightPathError) as exc:
        print(f"radseek simulate-dataset: {exc}", file=sys.stderr)
        return 2
    write_dataset(out, ds.frames, ds.scenario)
    if ds.truth is not None:
        atomic_write_json(out / "truth.json", ds.truth.to_dict())
    f = ds.frames
    effects = ", ".join(scene.enabled_effects()) or "none"
    print(f"wrote {out}: {len(f)} frames, {f.t[-1]:.1f} s, {int(f.dwell.max()) + 1} dwell points, "
          f"{int(f.counts.sum())} counts; scene {scene.name!r}, effects: {effects}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
