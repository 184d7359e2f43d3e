"""pydecay's tables read without importing pydecay (detector_fw_sim.xcom for materials, radseek.photon_lines'
machine cache for a nuclide's lines): the same values as pydecay's own API, and a process with a warm cache (a
run's detector, vehicle and launcher) never imports pydecay (0.3 s of CPU each)."""

import json
import os
import subprocess
import sys

import numpy as np
import pydecay
import pytest

from detector_fw_sim import xcom
from radseek import photon_lines


def test_every_material_has_pydecays_names_densities_and_interpolated_values():
    assert xcom.material_names() == list(pydecay.available_materials())
    rng = np.random.default_rng(1)
    for name in xcom.material_names():
        mat = pydecay.material(name)
        lo, hi = xcom.table()[name]["E_MeV"][0], xcom.table()[name]["E_MeV"][-1]
        e = np.r_[lo, hi, np.exp(rng.uniform(np.log(lo), np.log(hi), 200)), xcom.table()[name]["E_MeV"][3]]
        np.testing.assert_allclose(xcom.mu_over_rho(name, e), [mat.mu_over_rho(x) for x in e], rtol=1e-13)
        assert xcom.density_g_cm3(name.upper()) == mat.density_g_cm3
        for outside in (lo * (1 - 1e-9), hi * (1 + 1e-9), float("nan")):
            with pytest.raises(pydecay.MaterialError):
                mat.mu_over_rho(outside)
            with pytest.raises(ValueError, match="outside the table range"):
                xcom.mu_over_rho(name, [0.662, outside])
    with pytest.raises(ValueError, match="unknown material 'unobtainium'; known: air"):
        xcom.density_g_cm3("unobtainium")


def test_a_nuclides_lines_from_the_cache_are_the_computed_ones_and_a_damaged_file_is_computed_again(
        tmp_path, monkeypatch):
    monkeypatch.setenv("RADSEEK_CACHE_DIR", str(tmp_path))
    photon_lines.gamma_lines.cache_clear()
    computed = photon_lines.gamma_lines("Eu-152")
    files = list(photon_lines.lines_cache().glob("Eu-152@*.json"))
    assert len(files) == 1 and json.loads(files[0].read_text())[0] == list(computed[0])
    photon_lines.gamma_lines.cache_clear()
    assert photon_lines.gamma_lines("Eu-152") == computed
    files[0].write_text('[[1.0, "x"]')  # damaged: not read, computed and written again
    photon_lines.gamma_lines.cache_clear()
    assert photon_lines.gamma_lines("Eu-152") == computed
    assert json.loads(files[0].read_text())[0] == list(computed[0])
    photon_lines.gamma_lines.cache_clear()
    with pytest.raises(ValueError, match="unknown nuclide 'Xx-999'"):
        photon_lines.gamma_lines("Xx-999")
    photon_lines.gamma_lines.cache_clear()


START = """
import sys
from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.scene import load_scene
scene = load_scene("lattice-wall")
emulator = DetectorEmulator(scene, seed=0)
print(repr(("pydecay" in sys.modules, [w.material for w in scene.walls], emulator.draw_many.__name__)))
"""


@pytest.mark.io
def test_a_process_with_a_warm_cache_builds_a_walled_scenes_detector_without_importing_pydecay(tmp_path):
    env = {**os.environ, "RADSEEK_CACHE_DIR": str(tmp_path)}
    cold, warm = (subprocess.run([sys.executable, "-c", START], capture_output=True, text=True, env=env, timeout=120)
                  for _ in range(2))
    assert cold.returncode == 0 and warm.returncode == 0, cold.stderr + warm.stderr
    imported_cold, walls, _ = eval(cold.stdout)  # noqa: S307 - our own repr
    imported_warm, walls_warm, _ = eval(warm.stdout)  # noqa: S307
    assert walls and walls == walls_warm
    assert imported_cold and not imported_warm
