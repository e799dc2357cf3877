"""Force terms: the `ForceTerm` interface (`base.py`), its registry (`registry.py`) and every term beyond
the linear core, one module each (viscous, Morison, second order; nonlinear hydrostatics and
Froude–Krylov in `nonlinear/`). Recipe for a new term: docs/force-terms.md."""
