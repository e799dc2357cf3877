"""Nonlinear hydrostatics and Froude–Krylov forces on the instantaneous wetted surface.

One naming scheme: `term.py` is the force term; each concept has a plain-numpy module (`hull.py`:
the hull and its pressure integral; `elevation_series.py` and `pressure_boxes.py`: the incident
wave by series) that is the reference its compiled kernel is tested against; `kernels.py` holds what
callers need of the compiled code without numba (typed tables, thin wrappers, `HullPass`) and
`kernels_numba.py` is the only module that compiles (numba, imported on first use). Plain loop code
that runs as it is on the numpy path and is compiled by `kernels_numba.py` on the compiled one:
`rows.py`, `vector_math.py`, `cut_hull_loop.py`; `hull_kernel.py` calls the compiled cut-hull
integral."""
