"""The loads along a body (server/loads/sections.py) at rest: a uniform box barge whose mass line
carries a point mass amidships, in still water. Its shear, axial force and bending moment at every
station are written here from statics (buoyancy rho g B T per metre against the weight per metre, the
end faces' hydrostatic thrust rho g B T^2 / 2 at two thirds of the draft); the ends' loads vanish.
The panels' second moments make the linear pressure's integral exact (the one-point rule missed the
end face's moment by rho g B T h^2 / 12).
The scene's mass line that does not fit the body, or stations off the hull, are refused by key."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import body
from hydrolink.protocol.scene import Body
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.build.panels import PanelPressures
from hydrolink.server.loads.sections import section_cuts

RHO, G = 1025.0, 9.81
L, B, T = 20.0, 6.0, 2.0
POINT = 20000.0                        # kg amidships
PER_M = RHO * B * T - POINT / L        # kg/m: the rest, so the barge floats at its draft


def box_panels(size: float = 0.5) -> PanelPressures:
    """The box's wetted panels (bottom, sides, ends) of ``size`` metres, normals out of the body,
    no pressure data (statics only)."""
    centers, normals, areas, seconds = [], [], [], []

    def face(axis_u, axis_v, fixed, value, normal, lo_u, hi_u, lo_v, hi_v):
        nu, nv = round((hi_u - lo_u) / size), round((hi_v - lo_v) / size)
        for i in range(nu):
            for j in range(nv):
                c = np.zeros(3)
                c[axis_u], c[axis_v], c[fixed] = lo_u + (i + 0.5) * size, lo_v + (j + 0.5) * size, value
                centers.append(c)
                normals.append(normal)
                areas.append(size * size)
                spread = np.zeros(3)
                spread[[axis_u, axis_v]] = size ** 2 / 12          # a square's own second moments
                seconds.append(size * size * (np.outer(c, c) + np.diag(spread)))
    face(0, 1, 2, -T, (0, 0, -1), -L / 2, L / 2, -B / 2, B / 2)
    for y, n in ((-B / 2, (0, -1, 0)), (B / 2, (0, 1, 0))):
        face(0, 2, 1, y, n, -L / 2, L / 2, -T, 0.0)
    for x, n in ((-L / 2, (-1, 0, 0)), (L / 2, (1, 0, 0))):
        face(1, 2, 0, x, n, -B / 2, B / 2, -T, 0.0)
    p = len(areas)
    none = np.zeros((1, 6, p))
    return PanelPressures(body="barge", dofs=tuple(f"barge.{d}" for d in ("surge", "sway", "heave", "roll", "pitch",
                                                                           "yaw")),
                          reference_point=np.zeros(3), center=np.array(centers), normal=np.array(normals, float),
                          area=np.array(areas), second_moment=np.array(seconds), omega=np.array([1.0]), wave_direction=np.zeros(1), added_mass=none,
                          damping=none, added_mass_inf=none[0], excitation=np.zeros((1, 1, p), complex), rho=RHO, g=G,
                          source="(the test's box)")


def barge(stations, **sections) -> Body:
    mass = PER_M * L + POINT
    keys = {"stations": list(stations), "mass_stations": [-L / 2, L / 2], "mass_per_length": [PER_M],
            "point_masses": [[0.0, POINT]], **sections}
    return Body.model_validate(body("barge", hdb="barge.toml", mass=mass, center_of_mass=[0.0, 0.0, -1.0],
                                    inertia=[1e6, PER_M * L ** 3 / 12, PER_M * L ** 3 / 12], sections=keys))


def test_still_water_loads_of_a_box_with_a_point_mass_are_the_analytic_ones():
    stations = np.array([-10.0, -7.0, -3.0, -0.5, 0.5, 2.0, 6.0, 9.0, 10.0])
    b = barge(stations)
    cuts, _ = section_cuts(box_panels(), b.sections, b, "bodies[0].sections", RHO, G)
    q = POINT * G / L                                   # the net upward load per metre away from the point mass
    beyond = L / 2 - stations
    holds_point = stations < 0.0
    shear = -q * beyond + POINT * G * holds_point       # z: minus (buoyancy - weight) of the part beyond
    # y moment about the station's point on the mass line (z = -1): minus the water's and weight's;
    # the net vertical load q per metre (less the point mass at lever -s), and the far end face's thrust
    thrust = RHO * G * B * T ** 2 / 2                   # the water pushes the part beyond towards -x
    lever_z = -2 * T / 3 - (-1.0)
    moment = q * beyond ** 2 / 2 - POINT * G * (0.0 - stations) * holds_point + lever_z * thrust
    axial = np.full(stations.size, thrust)
    expected = np.c_[axial, np.zeros(stations.size), shear, np.zeros(stations.size), moment, np.zeros(stations.size)]
    expected[stations >= L / 2] = 0.0                   # nothing beyond the far end
    expected[stations <= -L / 2] = 0.0                  # the whole barge floats freely
    scale = POINT * G * L / 4                           # the largest bending moment
    for s, mine, ref in zip(stations, cuts.still, expected):
        print(f"s {s:+5.1f}  shear {mine[2]:+.6e} ({ref[2]:+.6e})  moment {mine[4]:+.6e} ({ref[4]:+.6e})")
    np.testing.assert_allclose(cuts.still, expected, atol=1e-9 * scale)


def test_a_mass_line_that_does_not_fit_the_body_is_refused_by_key():
    b = barge([0.0], mass_per_length=[PER_M * 1.01])
    with pytest.raises(ModelError, match="mass_per_length"):
        section_cuts(box_panels(1.0), b.sections, b, "bodies[0].sections", RHO, G)
    b = barge([12.0])
    with pytest.raises(ModelError, match="stations"):
        section_cuts(box_panels(1.0), b.sections, b, "bodies[0].sections", RHO, G)
    with pytest.raises(ValueError, match="sections: not with modes"):      # a flexible body: not built
        Body.model_validate({**barge([0.0]).model_dump(exclude_none=True), "modes": {"names": ["bend"], "mass": [1.0]}})
    with pytest.raises(ValueError, match="pressure_output: only for a wet body"):
        Body.model_validate(body("dry", mass=1.0, center_of_mass=[0.0, 0.0, 0.0], inertia=None, dofs=["heave"],
                                 pressure_output=True))
    b = barge([0.0], section_inertia=[[0.0, 0.0, 0.0]])
    _, warnings = section_cuts(box_panels(1.0), b.sections, b, "bodies[0].sections", RHO, G)
    assert any("section_inertia" in w for w in warnings)   # roll: the line has none, the body 1e6
