"""Second DEM engines behind the heap-test interface of :func:`calib_cli.dem.heap.run_heap`."""
