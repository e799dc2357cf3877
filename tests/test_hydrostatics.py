"""server/hydrostatics.py: the restoring stiffness is the HDB's buoyancy/waterplane part plus the
weight's moment about the moving reference point.

References written here: naval architecture's metacentric height (C44 = rho g V GM with
GM = KB + BM - KG, BM = I_wp / V) for a box and a vertical cylinder, and the righting moment of a
heeled box computed from the exact geometry of its immersed section (clipped polygon); through
HydroModel the same box's setup stiffness, net buoyancy and hydrostatic force.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import body, scene_toml
from hydrolink.protocol.scene import parse_scene
from hydrolink.protocol.hdb.schema import make_hdb
from hydrolink.server.hydrostatics import gravity_stiffness, total_stiffness
from hydrolink.server.model import HydroModel

RHO, G = 1000.0, 9.81
L, B, T, KG = 20.0, 8.0, 3.0, 2.5          # box length (x), beam (y), draft and centre of gravity above the keel


def hydro_block(area: float, ixx: float, iyy: float, volume: float, z_b: float, rho: float = RHO) -> np.ndarray:
    """The HDB's (WAMIT-convention) buoyancy and waterplane stiffness of a wall-sided body whose
    waterplane is centred on the reference point: C33 = rho g A_wp, C44 = rho g (I_xx + V z_b),
    C55 = rho g (I_yy + V z_b)."""
    c = np.zeros((6, 6))
    c[2, 2] = rho * G * area
    c[3, 3] = rho * G * (ixx + volume * z_b)
    c[4, 4] = rho * G * (iyy + volume * z_b)
    return c


def box_block() -> np.ndarray:
    return hydro_block(L * B, L * B ** 3 / 12, B * L ** 3 / 12, L * B * T, -T / 2)


def box_righting_moment(phi: float, mass: float, rho: float = RHO) -> float:
    """Roll moment about the x axis through the waterplane centre on the box heeled by ``phi``
    (heave held) in water of density ``rho``: buoyancy of the immersed part of the rotated section
    plus the rotated weight."""
    ys, zs = [-B / 2, B / 2, B / 2, -B / 2], [-T, -T, 2 * T, 2 * T]          # section, freeboard 2 T
    c, s = math.cos(phi), math.sin(phi)
    poly = [(y * c - z * s, y * s + z * c) for y, z in zip(ys, zs)]
    wet = _clip_below_waterline(poly)
    area, y_b = _area_and_centroid_y(wet)
    z_g = -T + KG
    return rho * G * L * area * y_b + mass * G * z_g * s        # y_B F_buoyancy + y_G (-m g), y_G = -z_g sin phi


def _clip_below_waterline(poly: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The part of a convex polygon (y, z) with z <= 0 (one Sutherland-Hodgman pass)."""
    out = []
    for (y0, z0), (y1, z1) in zip(poly, poly[1:] + poly[:1]):
        if z0 <= 0:
            out.append((y0, z0))
        if (z0 <= 0) != (z1 <= 0):
            f = z0 / (z0 - z1)
            out.append((y0 + f * (y1 - y0), 0.0))
    return out


def _area_and_centroid_y(poly: list[tuple[float, float]]) -> tuple[float, float]:
    """Area and centroid y of a simple polygon (shoelace)."""
    a = cy = 0.0
    for (y0, z0), (y1, z1) in zip(poly, poly[1:] + poly[:1]):
        cross = y0 * z1 - y1 * z0
        a += cross
        cy += (y0 + y1) * cross
    return abs(a) / 2, cy / (3 * a)


def test_gravity_block_is_the_weight_moment_about_the_reference_point():
    """C44, C55 -= m g (z_G - z_R); C46, C56 from the horizontal offset; nothing translational."""
    mass, cog, ref = 5.0e4, np.array([1.5, -0.7, 0.4]), np.array([0.2, 0.3, -1.0])
    c = gravity_stiffness(mass, cog, ref, G)
    d = cog - ref
    expected = np.zeros((6, 6))
    expected[3, 3] = expected[4, 4] = -mass * G * d[2]
    expected[3, 5], expected[4, 5] = mass * G * d[0], mass * G * d[1]
    np.testing.assert_allclose(c, expected, rtol=1e-15)
    # a yaw about R swings G sideways: the weight's roll moment changes by m g dx per radian
    tiny = 1e-7
    moment_roll = (np.cross([-tiny * d[1], tiny * d[0], 0.0], [0, 0, -mass * G]))[0]   # (theta x d) x W
    assert -moment_roll / tiny == pytest.approx(c[3, 5], rel=1e-9)


def test_box_and_cylinder_stiffness_is_m_g_gm():
    """Two floating bodies (m = rho V): heave rho g A_wp, roll and pitch rho g V GM with
    GM = KB + BM - KG; each gravity block on its own diagonal, the coupling block untouched."""
    r, t_c, kg_c = 2.0, 6.0, 4.0
    v_box, v_cyl = L * B * T, math.pi * r ** 2 * t_c
    c_hydro = np.zeros((12, 12))
    c_hydro[:6, :6] = box_block()
    c_hydro[6:, 6:] = hydro_block(math.pi * r ** 2, math.pi * r ** 4 / 4, math.pi * r ** 4 / 4, v_cyl, -t_c / 2)
    c_hydro[2, 8] = c_hydro[8, 2] = 123.0                      # a made-up coupling entry: kept as is
    refs = np.array([[0.0, 0.0, 0.0], [30.0, 5.0, 0.0]])
    cogs = refs + [[0.0, 0.0, -T + KG], [0.0, 0.0, -t_c + kg_c]]
    c = total_stiffness(c_hydro, np.array([RHO * v_box, RHO * v_cyl]), cogs, refs, G)
    gm_t = T / 2 + B ** 2 / (12 * T) - KG
    gm_l = T / 2 + L ** 2 / (12 * T) - KG
    gm_c = t_c / 2 + r ** 2 / (4 * t_c) - kg_c
    assert c[2, 2] == pytest.approx(RHO * G * L * B, rel=1e-14)
    assert c[3, 3] == pytest.approx(RHO * G * v_box * gm_t, rel=1e-12)
    assert c[4, 4] == pytest.approx(RHO * G * v_box * gm_l, rel=1e-12)
    assert c[9, 9] == pytest.approx(RHO * G * v_cyl * gm_c, rel=1e-12)
    assert c[10, 10] == c[9, 9] and c[8, 8] == pytest.approx(RHO * G * math.pi * r ** 2, rel=1e-14)
    assert gm_c < 0 < gm_t                                     # the tall cylinder is unstable: C < 0
    np.testing.assert_array_equal(c[:6, 6:], c_hydro[:6, 6:])
    assert c[2, 8] == 123.0


def test_box_stiffness_is_the_slope_of_its_exact_righting_moment():
    """C44 of hydrostatics + gravity equals -dM/dphi of the heeled box's geometric righting moment."""
    mass = RHO * L * B * T
    c = total_stiffness(box_block(), np.array([mass]), np.array([[0.0, 0.0, -T + KG]]), np.zeros((1, 3)), G)
    h = 1e-5
    slope = -(box_righting_moment(h, mass) - box_righting_moment(-h, mass)) / (2 * h)
    assert slope == pytest.approx(c[3, 3], rel=1e-8)
    assert box_righting_moment(0.0, mass) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("mass_ratio", [1.0, 0.8])
def test_model_setup_and_force_of_a_floating_box(mass_ratio):
    """Through HydroModel, the scene's water (rho 1025) rescaling the HDB's (rho 1000): setup
    stiffness = rho_s g V GM_T at m = rho_s V, net buoyancy = rho_s g V - m g, and the hydrostatic
    roll moment of a small heel is the geometric righting moment."""
    rho_s, v = 1025.0, L * B * T
    mass = mass_ratio * rho_s * v
    hdb = make_hdb(bodies=["box"], omega=np.array([0.5, 1.0]), wave_direction=np.array([0.0]),
                   added_mass=np.zeros((2, 6, 6)), radiation_damping=np.zeros((2, 6, 6)),
                   excitation_force=np.zeros((2, 1, 6), complex), hydrostatic_stiffness=box_block(),
                   reference_point=np.zeros((1, 3)), rho=RHO, g=G, water_depth=math.inf, source="closed form",
                   added_mass_inf=np.eye(6), displaced_volume=np.array([v]),
                   center_of_buoyancy=np.array([[0.0, 0.0, -T / 2]]))
    scene = parse_scene(scene_toml(dt=0.1, duration=1.0, water={"density": rho_s, "gravity": G},
                                   hydro={"irf_duration": 1.0}, bodies=[body("box", hdb="box.nc", mass=mass, center_of_mass=[0, 0, -T + KG],
                                                inertia=[1e7, 1e7, 1e7])]))
    model = HydroModel(scene, {"box": hdb})
    setup = model.setup_info()
    c44 = rho_s * G * (L * B ** 3 / 12 - v * T / 2) - mass * G * (-T + KG)
    assert setup.hydrostatic_stiffness[3, 3] == pytest.approx(c44, rel=1e-12)
    if mass_ratio == 1.0:
        assert c44 == pytest.approx(rho_s * G * v * (T / 2 + B ** 2 / (12 * T) - KG), rel=1e-12)
    assert setup.net_buoyancy[0] == pytest.approx((rho_s * v - mass) * G, rel=1e-12, abs=1e-6)
    phi = 1e-3
    heeled = setup.equilibrium_position.copy()
    heeled[0, 3] += phi
    f = model.step(0.0, heeled, np.zeros((1, 6)))["hydrostatic"][0]
    assert f[3] == pytest.approx(box_righting_moment(phi, mass, rho_s), rel=1e-5)
    assert f[2] == pytest.approx(0.0, abs=1e-9) and f[4] == pytest.approx(0.0, abs=1e-9)
