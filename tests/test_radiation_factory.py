"""The radiation factory (server/radiation/options.py): each option's own checks and setup report,
on hand-made groups, against closed forms and hand-computed values (no HydroModel, no HDB file)."""

from __future__ import annotations

import numpy as np
import pytest

import analytic_hdb as an
from hydrolink.protocol.scene import Hydro, RegularWave, StillWater
from hydrolink.server.errors import ModelError
from hydrolink.server.radiation.convolution import RadiationMemory
from hydrolink.server.radiation.options import ConstantDamping, PairCount, RadiationGroup, prune_pairs, radiation_option
from hydrolink.server.radiation.state_space import StateSpaceRadiation, evaluate

STILL = StillWater(type="still")
REGULAR = RegularWave(type="regular", height=1.0, period=5.0)
A_INF, B0, W0 = 3.0e5, 8.0e4, 1.0   # the analytic heave pair of analytic_hdb


def heave_group(omega: np.ndarray, added_mass: np.ndarray, damping: np.ndarray,
                a_inf: float | None = A_INF) -> RadiationGroup:
    """One body, heave only (row 2 of the 6N vectors, position 0 of the reduced ones)."""
    return RadiationGroup(source="hand", bodies=("float",), act=np.array([2]), pos=np.array([0]),
                          labels=("float.heave",), omega=omega, added_mass=added_mass[:, None, None],
                          damping=damping[:, None, None],
                          added_mass_inf=None if a_inf is None else np.array([[a_inf]]))


def analytic_group(omega=None, a_inf: float | None = A_INF) -> RadiationGroup:
    om = np.linspace(0.02, 8.0, 400) if omega is None else omega
    return heave_group(om, an.added_mass(om, A_INF, B0, W0), an.damping(om, B0, W0), a_inf)


# ----------------------------------------------------------------------------------- factory

def test_unknown_option_names_hydro_radiation():
    hydro = Hydro.model_construct(radiation="bem-on-the-fly")  # past the scene's own validation
    with pytest.raises(ModelError, match=r"^hydro\.radiation: unknown option 'bem-on-the-fly': one of "
                                         r"\['constant', 'convolution', 'off', 'state-space'\]"):
        radiation_option(hydro, STILL, 0.01)


@pytest.mark.parametrize("name", ["convolution", "state-space", "constant", "off"])
def test_each_option_reports_its_name_and_irf_grid(name):
    """irf_samples = round(T / dt), irf_duration = samples dt (T = 7.3 s, dt = 0.25: 29 samples, 7.25 s);
    "constant" keeps no memory: 0 and 0 s whatever irf_duration says."""
    opt = radiation_option(Hydro(radiation=name, irf_duration=7.3), REGULAR, 0.25)
    samples = 0 if name == "constant" else 29
    assert opt.name == name and opt.samples == samples
    rep = opt.build([], 6).report
    assert rep.radiation == name and rep.irf_samples == samples and rep.irf_duration == 0.25 * samples
    assert (rep.state_space is not None) == (name == "state-space")
    assert (rep.radiation_frequency is not None) == (name == "constant")


# --------------------------------------------------------------------------------- IRF stage

def test_aliasing_refused_naming_irf_duration():
    """Grid spacing 0.25 rad/s from 0: K repeats every 2 pi/0.25 = 25.13 s, aliasing time
    pi/0.25 = 12.57 s. At 25 s the IRF holds the mirror of K(0.13 s), nearly max |K|: refused."""
    om = np.arange(0.25, 8.0 + 1e-9, 0.25)
    opt = radiation_option(Hydro(irf_duration=25.0), STILL, 0.05)
    with pytest.raises(ModelError, match=r"^hydro\.irf_duration: 25 s reaches past the aliasing time "
                                         r"pi/d_omega = 12\.6 s of the HDB grid of 'hand'.*hydro\.irf_duration "
                                         r"<= 12\.6 s.*hydro\.irf_domega <= 0\.126 rad/s"):
        opt.build([analytic_group(om)], 6)


def test_aliasing_warned_when_the_mirror_is_small_and_resampling_removes_it():
    """At 14 s the mirror is K(25.13 - 14 = 11.1 s), ~1e-13 of max |K| (closed form): a warning;
    irf_domega = 0.02 (aliasing time 157 s) removes it."""
    om = np.arange(0.25, 8.0 + 1e-9, 0.25)
    rad = radiation_option(Hydro(irf_duration=14.0), STILL, 0.05).build([analytic_group(om)], 6)
    assert len(rad.warnings) == 1
    assert rad.warnings[0].startswith("hydro.irf_duration: 14 s reaches past the aliasing time pi/d_omega = 12.6 s")
    assert an.irf(11.1, B0, W0) / an.irf(0.0, B0, W0) < 1e-12
    fine = radiation_option(Hydro(irf_duration=14.0, irf_domega=0.02), STILL, 0.05).build([analytic_group(om)], 6)
    assert fine.warnings == []


def test_ogilvie_a_inf_when_the_hdb_has_none():
    """No A_inf in the group: Ogilvie's from the IRF recovers the closed form's A_inf."""
    rad = radiation_option(Hydro(irf_duration=30.0, radiation="off"), STILL, 0.01).build(
        [analytic_group(a_inf=None)], 6)
    assert rad.report.added_mass_inf_source == {"float": "ogilvie"}
    assert rad.added_mass_inf[2, 2] == pytest.approx(A_INF, rel=2e-3)


def test_taper_and_tail_reported_and_applied():
    """irf_taper = 0.5 of 20 s (window 1 up to 10 s, 0 at 20 s): the convolution's kernel is the
    closed-form K over the first 5 s (to the HDB grid's accuracy) and zero at 20 s."""
    hydro = Hydro(irf_duration=20.0, irf_taper=0.5, irf_tail="asymptotic")
    rad = radiation_option(hydro, STILL, 0.05).build([analytic_group()], 6)
    rep = rad.report
    assert (rep.irf_taper, rep.irf_tail, rep.irf_domega) == (0.5, "asymptotic", None)
    assert set(rep.tail_exponent) == {"hand"}
    mem = rad.forces[0][1]
    assert isinstance(mem, RadiationMemory)
    v = np.zeros(1)
    f0 = mem.push(np.ones(1))[0]              # -dt/2 K(0)
    assert f0 == pytest.approx(-0.025 * an.irf(0.0, B0, W0), rel=2e-3)
    k = np.array([-mem.push(v)[0] / 0.05 for _ in range(400)])  # K(j dt), j = 1..400
    t = 0.05 * np.arange(1, 401)
    early = t <= 5.0
    assert np.abs(k[early] - an.irf(t[early], B0, W0)).max() < 2e-3 * an.irf(0.0, B0, W0)
    assert k[-1] == pytest.approx(0.0, abs=1e-12 * an.irf(0.0, B0, W0))  # the taper's end


# ------------------------------------------------------------------------------- convolution

def test_prune_pairs_hand_computed():
    """Bodies 0 (DOFs 0, 1) and 1 (DOF 2); tolerance 0.01. Block (0, 1): max N = 0.015 vs
    0.01 sqrt(4 x 9) = 0.06 -> dropped both ways; pair (0, 1) inside body 0: 0.03 vs
    0.01 sqrt(4 x 1) = 0.02 -> kept; with 0.015 it would be dropped."""
    norms = np.array([[4.0, 0.03, 0.015],
                      [0.03, 1.0, 0.001],
                      [0.015, 0.001, 9.0]])
    body_of = np.array([0, 0, 1])
    keep, dropped = prune_pairs(norms, body_of, 0.01)
    assert keep.tolist() == [[True, True, False], [True, True, False], [False, False, True]]
    assert dropped.tolist() == [[False, True], [True, False]]
    norms[0, 1] = norms[1, 0] = 0.015
    keep, _ = prune_pairs(norms, body_of, 0.01)
    assert not keep[0, 1] and not keep[1, 0] and keep.diagonal().all()
    keep, dropped = prune_pairs(norms, body_of, 0.0)
    assert keep.all() and not dropped.any()


def test_pair_count_fractions():
    assert PairCount(kept=7, total=9, blocks_total=6, blocks_dropped=2).dropped_pair_fraction == pytest.approx(2 / 9)
    assert PairCount(kept=7, total=9, blocks_total=6, blocks_dropped=2).dropped_block_fraction == pytest.approx(1 / 3)
    assert PairCount().dropped_pair_fraction == 0.0 and PairCount().dropped_block_fraction == 0.0


def test_convolution_off_at_zero_duration_keeps_a_inf():
    """irf_duration = 0: no memory, no pairs; A_inf (from the group) in the client's mass matrix."""
    rad = radiation_option(Hydro(irf_duration=0.0), STILL, 0.01).build([analytic_group()], 6)
    assert rad.forces == [] and rad.report.pairs.kept == 0 and rad.report.irf_fit_error == {}
    assert rad.added_mass[2, 2] == rad.added_mass_inf[2, 2] == A_INF
    assert np.count_nonzero(rad.added_mass) == 1


# ------------------------------------------------------------------------------- state-space

def test_state_space_needs_two_steps_of_irf():
    """irf_duration = 0.01 s at dt = 0.01 s is one step: refused naming hydro.irf_duration."""
    with pytest.raises(ModelError, match=r"^hydro\.irf_duration: 0\.01 s: the state-space fit .* at least two "
                                         r"time steps"):
        radiation_option(Hydro(radiation="state-space", irf_duration=0.01), STILL, 0.01)
    assert radiation_option(Hydro(radiation="state-space", irf_duration=0.02), STILL, 0.01).samples == 2


def test_state_space_fit_reproduces_the_closed_form_transfer_function():
    """H(w) = B(w) + i w (A(w) - A_inf) of the analytic pair (closed forms of analytic_hdb); a 30 s
    IRF of this fast-decaying K is its whole: the realisation matches H within the tolerance (plus
    the HDB grid's trapezoid error), and the report counts its states."""
    rad = radiation_option(Hydro(radiation="state-space", irf_duration=30.0, ss_tolerance=0.01), STILL,
                           0.05).build([analytic_group()], 6)
    ss = rad.forces[0][1]
    assert isinstance(ss, StateSpaceRadiation) and np.all(ss.poles.real < 0)
    w = np.linspace(0.05, 6.0, 300)
    h = evaluate(1j * w, ss.poles[None], ss._c2[None] / 2, np.array([ss.d[0, 0]]))[0]
    exact = an.damping(w, B0, W0) + 1j * w * (an.added_mass(w, A_INF, B0, W0) - A_INF)
    assert np.abs(h - exact).max() < 0.015 * np.abs(exact).max()
    st = rad.report.state_space
    assert st["pairs"] == 1 and st["states"] == ss.states == 2 * ss.poles.size and st["unmet"] == 0
    assert 0 < st["max_fit_error"] <= 0.01 and st["worst_pair"] == "(float.heave, float.heave)"
    assert rad.added_mass[2, 2] == A_INF


# ---------------------------------------------------------------------------------- constant

def test_constant_needs_regular_waves():
    with pytest.raises(ModelError, match=r'^hydro\.radiation: "constant" .* needs \[waves\] type = "regular" '
                                         r"\(got 'still'\)"):
        radiation_option(Hydro(radiation="constant"), STILL, 0.01)


def test_constant_reports_a_and_b_at_w0():
    """A(w) = 2e5 + 5e4 w and B(w) = 3e4 w are linear, so interpolation is exact: at
    w0 = 2 pi/5 the client gets A(w0) and the force is -B(w0) v; A_inf stays the group's."""
    om = np.linspace(0.1, 4.0, 40)
    w0 = 2 * np.pi / 5.0
    rad = radiation_option(Hydro(radiation="constant"), REGULAR, 0.01).build(
        [heave_group(om, 2e5 + 5e4 * om, 3e4 * om, a_inf=1.5e5)], 6)
    assert rad.report.radiation_frequency == pytest.approx(w0, rel=1e-15)
    assert rad.added_mass[2, 2] == pytest.approx(2e5 + 5e4 * w0, rel=1e-13)
    assert rad.added_mass_inf[2, 2] == 1.5e5
    force = rad.forces[0][1]
    assert isinstance(force, ConstantDamping)
    assert force.push(np.array([0.7]))[0] == pytest.approx(-3e4 * w0 * 0.7, rel=1e-13)


def test_constant_refuses_w0_outside_the_hdb():
    """w0 = 2 pi/5 = 1.257 rad/s above a grid ending at 1.0 rad/s: refused naming waves.period."""
    om = np.linspace(0.1, 1.0, 10)
    opt = radiation_option(Hydro(radiation="constant"), REGULAR, 0.01)
    with pytest.raises(ModelError, match=r"^waves\.period: w0 = 1\.257 rad/s lies outside the HDB's range "
                                         r"0\.1\.\.1 rad/s"):
        opt.build([heave_group(om, 2e5 + 0 * om, 3e4 * om)], 6)


# ----------------------------------------------------------------------------------------- off

def test_off_has_no_force_and_keeps_a_inf():
    rad = radiation_option(Hydro(radiation="off"), STILL, 0.01).build([analytic_group()], 6)
    assert rad.forces == [] and rad.report.pairs.total == 0
    assert rad.added_mass[2, 2] == rad.added_mass_inf[2, 2] == A_INF
    assert rad.report.added_mass_inf_source == {"float": "hdb"}
    assert rad.report.irf_fit_error["hand"] < 1e-3  # K reproduces B (the closed-form pair, 40 s)


def test_constant_radiation_takes_a_wide_period_grid_without_irf_settings():
    """Issue 38 item 5: an HDB on periods 0.15-150 s (uniform in period: its aliasing time pi/d_omega
    is 0.09 s at the short end) with radiation = "constant" and the default irf_duration: no IRF
    setting is demanded (before: refused, "40 s reaches past the aliasing time"); the force is
    -B(w0) v and the client's added mass A(w0), both the HDB's interpolated at w0 = 2 pi / 8 s."""
    periods = np.linspace(0.15, 150.0, 200)
    om = np.sort(2 * np.pi / periods)
    a, b = an.added_mass(om, A_INF, B0, W0), an.damping(om, B0, W0)
    w0 = 2 * np.pi / 8.0
    waves = RegularWave(type="regular", height=1.0, period=8.0)
    rad = radiation_option(Hydro(radiation="constant"), waves, 0.05).build([heave_group(om, a, b)], 6)
    assert rad.warnings == [] and rad.report.irf_samples == 0
    assert rad.added_mass[2, 2] == pytest.approx(np.interp(w0, om, a), rel=1e-12)
    (pos, force), = rad.forces
    assert force.push(np.array([0.7]))[0] == pytest.approx(-np.interp(w0, om, b) * 0.7, rel=1e-12)
    with pytest.raises(ModelError, match="reaches past the aliasing time"):   # a memory does need them
        radiation_option(Hydro(), waves, 0.05).build([heave_group(om, a, b)], 6)
