"""The library API: one plain function per stage of a calibration, on a run directory (docs/library.md).

run_dir.init_run, measure.measure_angle, doe.{pb,ascent,bbd}_{design,analyze}, simulate.simulate_heap,
surrogate.fit_surrogate, invert.invert, compare.compare, diagnose.diagnose, lab.synth_lab: each takes
the run directory and the command's options and returns a result with ``summary()``; the commands in
calib_cli.cli parse options, call them and print.
"""
