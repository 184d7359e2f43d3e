"""Bundled scene files (TOML), read by ``detector_fw_sim.scene.load_scene``; a package so wheels ship them."""
