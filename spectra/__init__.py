"""Real detector data: the physical response fitted to measured spectra (``radseek calibrate``), flight conversion
and N42 export. A tool package like ``launch``: it uses the simulator's physics (``detector_fw_sim.response``) and
writes the contracts' detector file (``radseek_io.detector_file``), which the estimator reads without the simulator."""
