"""The HDB map of `hello` (protocol/hdb/wire.py, SPEC §5.1): exact round trip through the codec, the
exp(−iωt) convention on the wire, and errors that name the entry and field."""

from __future__ import annotations

import numpy as np
import pytest

from hydrolink.protocol import codec
from hydrolink.protocol.hdb.wire import from_wire, to_wire
from hydrolink.protocol.hdb.layout import HDBError

HEAVE = 2


@pytest.fixture(scope="module")
def rm3(reference_data):
    """The RM3 WAMIT HDB (float + spar), exp(+iωt) on file, read into the internal convention."""
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1")


def through_codec(data: dict) -> dict:
    msg = codec.unpack(codec.pack(codec.message("hello", 1, None, hdbs={"rm3.1": data})))
    return codec.decode_tree(msg["hdbs"]["rm3.1"])


def test_round_trip_is_exact(rm3):
    back = from_wire(through_codec(to_wire(rm3)), "rm3.1")
    for name in ("added_mass", "radiation_damping", "excitation_force", "hydrostatic_stiffness",
                 "reference_point", "added_mass_inf"):
        assert np.array_equal(back[name].values, rm3[name].values), name
    assert list(back["body"].values) == ["float", "spar"]
    assert back.attrs["rho"] == rm3.attrs["rho"] and np.isinf(back.attrs["water_depth"])


def test_excitation_travels_in_the_exp_minus_iwt_convention(rm3):
    """RM3 float heave at ω = 0.7854 rad/s (T = 8 s, interpolated on the 0.02 rad/s grid): |X| =
    1.512e6 N/m and a phase of −17° on the wire, where WAMIT's exp(+iωt) file has +17°."""
    wire = to_wire(rm3)
    x = wire["excitation_force"][:, 0, HEAVE]
    x = complex(np.interp(0.7854, wire["omega"], x.real), np.interp(0.7854, wire["omega"], x.imag))
    assert abs(x) == pytest.approx(1.512e6, rel=2e-3)
    assert np.degrees(np.angle(x)) == pytest.approx(-17.0, abs=0.5)


@pytest.mark.parametrize("field", ["omega", "added_mass", "attrs"])
def test_a_missing_field_is_named(rm3, field):
    data = to_wire(rm3)
    del data[field]
    with pytest.raises(HDBError, match=f"rm3.1.*{field}.*missing field"):
        from_wire(data, "rm3.1")


def test_arrays_that_do_not_fit_are_refused(rm3):
    data = to_wire(rm3)
    data["added_mass"] = data["added_mass"][:, :6, :6]
    with pytest.raises(HDBError, match="rm3.1"):
        from_wire(data, "rm3.1")
