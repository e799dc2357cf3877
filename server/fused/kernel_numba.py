"""The fused linear step compiled (numba; imported only from server/fused/step.py, on first use).

The fixed inputs and the state live in one :class:`LinearState` made once per session, so a step's
call passes that object and the step's own values: numba's dispatch types every array argument
on every call (about 0.1-0.2 µs each; the loops take some thirty).
"""

from __future__ import annotations

from hydrolink.server import compiler
from hydrolink.server.fused import loops

numba = compiler.load()      # numba as server/compiler.py sets it up
from numba.core import types  # (after numba's set-up above)
from numba.experimental import structref

_jit = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})

excitation = _jit(loops.excitation)
# the convolution's sums reassociated, so that they vectorise: a long dot product (L na terms) is
# bound by the adds' latency otherwise (3x slower than BLAS's; with it 1.3-1.7x; round-off of the same size)
convolution = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract", "reassoc"})(
    loops.convolution)
state_space = _jit(loops.state_space)
hydrostatic = _jit(loops.hydrostatic)
gather = _jit(loops.gather)
yaw_excitation = _jit(loops.yaw_excitation)

FIELDS = ["idx", "exc", "omega", "ramp_t", "trig", "k_hs", "x_eq", "kind", "k", "data", "indices", "indptr", "live", "buf",
          "counters", "phi", "g0", "g1", "c2", "rows", "cols", "d", "z", "z_prev", "v_prev", "v_last", "vs", "f",
          "yaw_tables", "yaw_headings", "yaw_rows", "yaw_owner"]


class UnliteralStructRef(types.StructRef):
    """A structref type whose fields' types are taken as given, not literal (the base of this module's
    :class:`LinearState` type and of clients/exudyn/kernels/exchange.py's ``ExchangeState`` type)."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


@structref.register
class _LinearStateType(UnliteralStructRef):
    """numba's type of a :class:`LinearState`."""


class LinearState(structref.StructRefProxy):
    """The fused step's fixed inputs and state (server/fused/step.py ``FusedLinearStep``)."""


structref.define_proxy(LinearState, _LinearStateType, FIELDS)


@_jit
def linear_state(idx, exc, omega, ramp_t, trig, k_hs, x_eq, kind, k, data, indices, indptr, live, buf, counters,
                 phi, g0, g1, c2, rows, cols, d, z, z_prev, v_prev, v_last, vs, f, yaw_tables, yaw_headings,
                 yaw_rows, yaw_owner):
    """The :class:`LinearState` of these arrays (held, not copied)."""
    return LinearState(idx, exc, omega, ramp_t, trig, k_hs, x_eq, kind, k, data, indices, indptr, live, buf, counters,
                       phi, g0, g1, c2, rows, cols, d, z, z_prev, v_prev, v_last, vs, f, yaw_tables, yaw_headings,
                       yaw_rows, yaw_owner)


@_jit
def step(st, t, x, v, replace, f_ext, eta_ext, out):
    """One step of the linear core into ``out`` (3, 6N): rows excitation, radiation, hydrostatic at
    the active DOFs (the rest left as they are), server/fused/loops.py's loops on ``st``'s arrays.
    Returns the wave elevation. ``x``, ``v`` (6N,) the state; ``f_ext`` (na,) and ``eta_ext`` an
    excitation and elevation computed outside (by convolution; zero otherwise), added to the
    components' sum."""
    gather(v, st.idx, st.vs)
    eta = excitation(st.idx, st.exc, st.omega, st.ramp_t, st.trig, t, f_ext, out[0]) + eta_ext
    yaw_excitation(st.yaw_tables, st.yaw_headings, st.yaw_rows, st.yaw_owner, st.idx, st.ramp_t, st.trig, t, f_ext,
                   out[0])
    if st.kind == 1 or st.kind == 2:
        convolution(st.k, st.data, st.indices, st.indptr, st.buf, st.counters, st.vs, replace, st.idx, st.live, out[1])
    elif st.kind == 3:
        state_space(st.phi, st.g0, st.g1, st.c2, st.rows, st.cols, st.d, st.z, st.z_prev, st.v_prev, st.v_last,
                    st.counters, st.vs, replace, st.f, st.idx, out[1])
    hydrostatic(st.k_hs, st.x_eq, st.idx, x, out[2])
    return eta
