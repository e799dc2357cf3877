"""Studies built on runs: sweeps on Dask, the grid of scene keys, accuracy benches, IEC power matrices, the steady-state solver."""
