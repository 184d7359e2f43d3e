"""Plot the emulated spectrum of a nuclide: fine measured spectrum and the 32 channels of one dwell.

    .venv/bin/python -m detector_fw_sim.spectrum_plot --nuclide Cs-137 --out docs/spectrum-cs137.png

The channel panel is one seeded Poisson draw of a 60 s dwell 1 m from the source, facing it, with
the default scene's background; the fine panel is the response (response.py) per incident photon.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from detector_fw_sim import response
from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.scene import load_scene, validate_scene


def plot(nuclide: str, out: str, seed: int = 0, dwell_s: float = 60.0) -> dict[str, float]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = load_scene().model_dump()
    data["sources"][0].update({"nuclide": nuclide})
    scene = validate_scene(data, f"default scene with {nuclide}")
    det = scene.detector
    em = DetectorEmulator(scene, seed=seed)
    src = np.array(scene.sources[0].position)
    pose = np.r_[src + np.array([-1.0, 0.0, 0.0]), 0.0]  # 1 m away, axis pointing at the source
    counts = em.draw(pose, 0.0, dwell_s)
    expected = em.expected_counts(pose[None, :], np.zeros(1), np.array([dwell_s]))[0]
    edges = em.channel_edges_keV

    grid = response.energy_grid()
    centres = 0.5 * (grid[1:] + grid[:-1])
    lines = response.nuclide_response(nuclide, det.crystal, det.fwhm_at_662, det.backscatter_fraction)
    fine = sum(r.photons_per_decay * np.diff(r.cdf) for r in lines) / response.GRID_STEP_KEV

    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 7), constrained_layout=True)
    ax1.semilogy(centres, np.maximum(fine, 1e-9), lw=1)
    ax1.set_xlim(0, 1.25 * max(e for e, _ in lines_main(nuclide)) + 200)
    ax1.set_ylim(1e-6, None)
    ax1.set_xlabel("measured energy (keV)")
    ax1.set_ylabel("counts per keV per decay (crystal face)")
    marks = {}
    for e, _ in lines_main(nuclide):
        edge = response.compton_edge_keV(e)
        back = float(response.scattered_energy_keV(e, np.pi))
        marks.update({f"photopeak {e:.0f}": e, f"Compton edge {edge:.0f}": edge, f"backscatter {back:.0f}": back})
    for i, (label, e) in enumerate(marks.items()):
        ax1.axvline(e, color=f"C{1 + i % 3}", ls="--", lw=0.8, label=f"{label} keV")
    ax1.legend(fontsize=8)
    ax1.set_title(f"{nuclide}: CsI(Tl) {det.crystal_diameter_mm:.0f}x{det.crystal_length_mm:.0f} mm, "
                  f"{100 * det.fwhm_at_662:.0f} % FWHM at 662 keV, Klein-Nishina continuum, backscatter "
                  f"{100 * det.backscatter_fraction:.0f} %", fontsize=9)
    widths = np.diff(edges)
    widths[-1] = widths[-2]
    ax2.bar(edges[:-1], counts, width=widths, align="edge", alpha=0.6,
            label=f"one {dwell_s:.0f} s dwell at 1 m (seed {seed})")
    ax2.step(edges[:-1], expected, where="post", color="k", lw=1, label="expected")
    ax2.set_xlabel("channel lower edge (keV); channel 31 = overflow above 1600 keV")
    ax2.set_ylabel("counts per channel")
    ax2.legend(fontsize=8)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return {"total_counts": float(counts.sum()), "peak_channel": int(np.argmax(expected[10:])) + 10}


def lines_main(nuclide: str) -> list[tuple[float, float]]:
    return [(e, y) for e, y in response.gamma_lines(nuclide) if e >= 100 and y > 0.05]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m detector_fw_sim.spectrum_plot", description=__doc__.splitlines()[0])
    p.add_argument("--nuclide", default="Cs-137")
    p.add_argument("--out", default="spectrum.png")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    info = plot(args.nuclide, args.out, args.seed)
    print(f"wrote {args.out}: {info}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
