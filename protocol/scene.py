"""The scene file (TOML): what to simulate. Parsed and validated identically by clients and server.

The scene travels in the ``hello`` message as its TOML text, so the server validates exactly what
the client read. Every error names the file, the key (``bodies[0].mass``) and why.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Collection, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationError, field_validator, model_validator

from hydrolink.protocol.capabilities import FEATURES
from hydrolink.protocol.current import Current
from hydrolink.protocol.errors import KeyedError
from hydrolink.protocol.scene_bounds import MAX_STEPS, AddedMassRatio, AngleDeg, Area, CableElements, Coefficient, Efficiency, ComponentCount, Coordinate, Density, Depth, Diameter, DirectionCount, Displacement, Duration, ExchangeSteps, ExcitationIRFDuration, EnergyFraction, ExplicitSpectralRadius, FileTime, FlowCoefficient, Fraction, Frequency, FrequencyStep, Gravity, HarmonicCount, IRFDuration, Interval, IterationCount, LatencySteps, Length, LineDensity, Mass, NonNegativeCoefficient, NonNegativeDiameter, NonNegativeLength, ParameterFloat, ParameterInt, PeakEnhancement, PositiveCoefficient, PreviewTime, RampTime, RegularisationSpeed, Seed, SegmentCount, SignificantHeight, SpectralRadius, Speed, SpreadingExponent, StateSpaceOrder, TimeStep, Tolerance, Volume, WallTimeout, WaveHeight, WavePeriod
from hydrolink.protocol.toml_model import read_toml_file, validate_toml

if TYPE_CHECKING:
    from hydrolink.protocol.hdb.external_matrices import ExternalMatrices

DOF_NAMES: tuple[str, ...] = ("surge", "sway", "heave", "roll", "pitch", "yaw")


log = logging.getLogger(__name__)


class SceneError(KeyedError):
    """A scene that cannot be run; the message names the file, the key and why."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)




class Simulation(_Section):
    dt: TimeStep
    duration: Duration
    progress: bool = True
    # Exudyn client: generalized-alpha spectral radius (1 = trapezoidal rule, no numerical damping;
    # < 1 damps the constraint forces of long runs with joint loops and slack ropes)
    spectral_radius: SpectralRadius = 1.0
    # s of wall time between results flushes (written + synced): a crash loses at most this much work
    flush_seconds: Interval = 1.0

    @model_validator(mode="after")
    def _step_count(self) -> "Simulation":
        steps = self.duration / self.dt
        if steps > MAX_STEPS:
            raise ValueError(f"duration: {self.duration:g} s at dt = {self.dt:g} s is {steps:.3g} steps; at most "
                             f"{MAX_STEPS:.0e} (a longer dt or a shorter duration)")
        return self

    @property
    def n_steps(self) -> int:
        return int(round(self.duration / self.dt))


class Water(_Section):
    density: Density = 1025.0
    gravity: Gravity = 9.81
    depth: Union[Literal["inf"], Depth] = "inf"

    @property
    def depth_m(self) -> float:
        return math.inf if self.depth == "inf" else float(self.depth)


class StillWater(_Section):
    type: Literal["still"]


# excitation (server/sea/waves.py): "superposition" sums Re{a X(w) e^{i(phi - w t)}} over the components;
# "convolution" convolves the non-causal excitation IRF K_ex over [-T_c, T_c] (T_c =
# excitation_irf_duration) with the elevation at the origin (synthesized from the same components)
Excitation = Literal["superposition", "convolution"]


class RegularWave(_Section):
    type: Literal["regular"]
    height: WaveHeight
    period: WavePeriod
    direction: AngleDeg = 0.0
    phase: AngleDeg = 0.0
    ramp: RampTime = 0.0
    excitation: Excitation = "superposition"
    excitation_irf_duration: ExcitationIRFDuration = 20.0


class IrregularWave(_Section):
    type: Literal["irregular"]
    spectrum: Literal["jonswap", "pierson-moskowitz"]
    hs: SignificantHeight
    tp: WavePeriod
    gamma: PeakEnhancement = 3.3
    seed: Seed = 0
    direction: AngleDeg = 0.0
    components: ComponentCount = 300
    ramp: RampTime = 0.0
    excitation: Excitation = "superposition"
    excitation_irf_duration: ExcitationIRFDuration = 20.0
    # directional spreading: D(theta) = C(s) cos^2s((theta - direction)/2), discretised into
    # ``directions`` equal-energy sectors (one heading each, at the sector's centroid)
    spreading: Literal["none", "cos2s"] = "none"
    s: SpreadingExponent | None = None     # default 10
    directions: DirectionCount | None = None                      # default 9
    # rad/s: the band the components span (HydroDyn's WvLowCOff/WvHiCOff); the spectrum's energy
    # outside it is left out by the scene's choice. Default: the HDB's whole range (and a setup
    # warning when more than 1 % of the energy falls outside it)
    omega_range: tuple[Frequency, Frequency] | None = None

    @field_validator("omega_range")
    @classmethod
    def _band(cls, band):
        if band is not None and not band[0] < band[1]:
            raise ValueError(f"[low, high] in rad/s with low < high (got {list(band)})")
        return band

    @model_validator(mode="after")
    def _spreading_keys(self) -> "IrregularWave":
        if self.spreading == "none":
            for key in ("s", "directions"):
                if getattr(self, key) is not None:
                    raise ValueError(f'{key}: only with spreading = "cos2s"')
        return self

    @property
    def spreading_s(self) -> float:
        return 10.0 if self.s is None else float(self.s)

    @property
    def spreading_directions(self) -> int:
        return 1 if self.spreading == "none" else (9 if self.directions is None else int(self.directions))


class ElevationWave(_Section):
    """A measured or prescribed elevation eta(t) at the origin (CSV: time, eta; NetCDF: variable
    ``eta`` over ``time``), unidirectional along ``direction``; excitation by convolution with the
    non-causal excitation IRF (server/sea/waves.py). ``start``: the file time at simulation t = 0
    (default: the file's first time + excitation_irf_duration, so the IRF's past is covered)."""
    type: Literal["elevation"]
    file: Annotated[str, Field(min_length=1)]       # relative to the scene file
    direction: AngleDeg = 0.0
    start: FileTime | None = None
    ramp: RampTime = 0.0
    excitation: Literal["convolution"] = "convolution"
    excitation_irf_duration: ExcitationIRFDuration = 20.0


class WaveSystem(_Section):
    """One wave system of ``[waves] type = "sea"`` (server/sea/seastate.py, docs/waves.md): a spectrum
    S(w) (JONSWAP, Pierson-Moskowitz, or a table ``omega``/``density``) spread around ``direction``
    (none, cos-2s of one ``s``, or Mitsuyasu's frequency-dependent s(w) = s_max (w/w_p)^5 below the
    peak, s_max (w/w_p)^-2.5 above), or a directional table S(w, theta) (``omega``, ``theta`` in
    degrees, ``density`` rows over omega). ``units = "hz-deg"``: the table's frequencies in Hz and
    its density per Hz (and per degree): a buoy's or MHKiT's spectrum as it comes."""
    spectrum: Literal["jonswap", "pierson-moskowitz", "table"]
    hs: SignificantHeight | None = None
    tp: WavePeriod | None = None
    gamma: PeakEnhancement = 3.3
    direction: AngleDeg = 0.0
    spreading: Literal["none", "cos2s", "mitsuyasu"] = "none"
    s: SpreadingExponent | None = None           # cos2s (default 10)
    s_max: SpreadingExponent | None = None       # mitsuyasu (default 10: wind sea; swell 25-75)
    directions: DirectionCount | None = None     # equal-energy sectors (default 9 when spread)
    omega: Annotated[list[Annotated[float, Field(gt=0.0, le=1000.0, allow_inf_nan=False)]], Field(min_length=2)] | None = None
    theta: Annotated[list[AngleDeg], Field(min_length=2)] | None = None
    density: list[Annotated[float, Field(allow_inf_nan=False)]] | list[list[Annotated[float, Field(allow_inf_nan=False)]]] | None = None
    units: Literal["rad", "hz-deg"] = "rad"
    # a table from a file instead of omega/theta/density (CSV or NetCDF; clients/scene_inputs.py
    # load_spectrum_files; it reaches the server in hello.spectra, SPEC §5.1)
    file: Annotated[str, Field(min_length=1)] | None = None

    @model_validator(mode="after")
    def _keys_of_the_spectrum(self) -> "WaveSystem":
        table = self.spectrum == "table"
        if self.file is not None:
            if not table:
                raise ValueError("file: only with spectrum = \"table\" (the file holds the table)")
            if (self.omega, self.theta, self.density) != (None, None, None):
                raise ValueError("file: the table comes from the file or from omega/theta/density, not both")
            if self.spreading != "none":
                raise ValueError("spreading: a directional table spreads itself (leave spreading = \"none\")")
            return self
        for key in ("hs", "tp"):
            if table and getattr(self, key) is not None:
                raise ValueError(f"{key}: not with spectrum = \"table\" (the table is the spectrum)")
            if not table and getattr(self, key) is None:
                raise ValueError(f"{key}: required with spectrum = \"{self.spectrum}\"")
        if not table and (self.omega, self.theta, self.density) != (None, None, None):
            raise ValueError("omega, theta, density: only with spectrum = \"table\"")
        if table:
            _check_table(self)
        if self.spreading == "mitsuyasu" and self.tp is None and not table:
            raise ValueError("tp: required by spreading = \"mitsuyasu\" (s depends on w/w_p)")
        for key, want in (("s", "cos2s"), ("s_max", "mitsuyasu")):
            if getattr(self, key) is not None and self.spreading != want:
                raise ValueError(f"{key}: only with spreading = \"{want}\"")
        if self.directions is not None and self.spreading == "none" and self.theta is None:
            raise ValueError("directions: only with a spreading or a directional table")
        return self

    def with_table(self, omega: list[float], theta: list[float] | None, density: list) -> "WaveSystem":
        """This system with the table of its ``file`` (validated as an inline one; ``file`` kept)."""
        inline = WaveSystem.model_validate({**self.model_dump(exclude={"file"}, exclude_none=True),
                                            "omega": omega, "theta": theta, "density": density})
        return inline.model_copy(update={"file": self.file})

    @property
    def sectors(self) -> int:
        """Directions the system is discretised into (1: unidirectional)."""
        spread = self.spreading != "none" or self.theta is not None
        return (9 if self.directions is None else int(self.directions)) if spread else 1


def _check_table(system: WaveSystem) -> None:
    """A table's shape, order and signs (every problem names the key)."""
    if system.omega is None or system.density is None:
        raise ValueError("omega, density: required with spectrum = \"table\"")
    n = len(system.omega)
    if any(b <= a for a, b in zip(system.omega, system.omega[1:])):
        raise ValueError("omega: must increase strictly")
    rows = system.density
    two_d = bool(rows) and isinstance(rows[0], list)
    if two_d != (system.theta is not None):
        raise ValueError("density: a list over omega with no theta, or rows over omega of values over theta")
    if len(rows) != n:
        raise ValueError(f"density: {len(rows)} rows for {n} frequencies (omega)")
    if two_d:
        m = len(system.theta)
        if any(len(r) != m for r in rows):
            raise ValueError(f"density: every row needs {m} values (one per theta)")
        if any(b <= a for a, b in zip(system.theta, system.theta[1:])) or system.theta[-1] - system.theta[0] >= 360.0:
            raise ValueError("theta: must increase strictly and span less than 360 degrees")
        if system.spreading != "none":
            raise ValueError("spreading: a directional table spreads itself (leave spreading = \"none\")")
    values = [v for r in rows for v in (r if two_d else [r])]
    neg = next((k for k, v in enumerate(values) if v < 0.0), None)
    if neg is not None:
        where = f"row {neg // len(system.theta)}, column {neg % len(system.theta)}" if two_d else f"entry {neg}"
        raise ValueError(f"density: a spectrum cannot be negative ({values[neg]:g} at {where})")
    if not any(v > 0.0 for v in values):
        raise ValueError("density: all zero (no sea)")


class SeaState(_Section):
    """``type = "sea"``: several wave systems at once (wind sea + swell), each its own spectrum,
    spreading and direction (server/sea/seastate.py). ``frequencies``: bins of equal width (as
    ``irregular``), of equal energy (each component at its bin's energy centroid, carrying E/N), or a
    table's own frequencies (``"table"``)."""
    type: Literal["sea"]
    systems: Annotated[list[WaveSystem], Field(min_length=1, max_length=16)]
    components: ComponentCount = 200
    frequencies: Literal["equal-width", "equal-energy", "table"] = "equal-width"
    seed: Seed = 0
    omega_range: tuple[Frequency, Frequency] | None = None
    ramp: RampTime = 0.0
    excitation: Excitation = "superposition"
    excitation_irf_duration: ExcitationIRFDuration = 20.0

    @model_validator(mode="after")
    def _table_frequencies(self) -> "SeaState":
        if self.frequencies == "table":
            bad = [i for i, s in enumerate(self.systems) if s.spectrum != "table"]
            if bad:
                raise ValueError(f"systems[{bad[0]}].spectrum: frequencies = \"table\" needs every system's own "
                                 "table of frequencies")
        if self.omega_range is not None and not self.omega_range[0] < self.omega_range[1]:
            raise ValueError(f"omega_range: [low, high] in rad/s with low < high (got {list(self.omega_range)})")
        return self

    @property
    def direction(self) -> float:
        """The first system's direction (deg): the sea's reference heading."""
        return self.systems[0].direction


class ComponentWaves(_Section):
    """``type = "components"``: a list of wave components replayed exactly (OpenFAST's WaveMod 7):
    eta(x, t) = sum a cos(k . x - w t + phase) with k along ``direction`` (deg, where the component
    travels to) and the phase in degrees (server/sea/seastate.py)."""
    type: Literal["components"]
    omega: Annotated[list[Frequency], Field(min_length=1, max_length=100_000)]
    direction: list[AngleDeg]
    amplitude: list[Annotated[float, Field(ge=0.0, le=50.0, allow_inf_nan=False)]]
    phase: list[AngleDeg]
    ramp: RampTime = 0.0
    excitation: Excitation = "superposition"
    excitation_irf_duration: ExcitationIRFDuration = 20.0

    @model_validator(mode="after")
    def _same_lengths(self) -> "ComponentWaves":
        n = len(self.omega)
        for key in ("direction", "amplitude", "phase"):
            if len(getattr(self, key)) != n:
                raise ValueError(f"{key}: {len(getattr(self, key))} values for {n} components (omega)")
        return self


class Gauge(_Section):
    """One wave gauge of ``[waves] type = "gauges"``: its position on the still-water plane and its
    elevation record (a file as ``type = "elevation"`` reads it: CSV time, eta or NetCDF ``eta``
    over ``time``). Its record is no scene key: Scene.with_gauges puts the file's (the client reads
    it and sends it in hello.gauges, SPEC §5.1), read back as ``time``/``eta``."""
    x: Coordinate
    y: Coordinate
    file: Annotated[str, Field(min_length=1)]       # relative to the scene file
    # what the record holds: the elevation (m), or the surface slope d eta/dx or d eta/dy (m/m) of a
    # pitch-roll buoy (NetCDF variable eta, slope_x, slope_y)
    quantity: Literal["elevation", "slope-x", "slope-y"] = "elevation"
    _record: tuple | None = PrivateAttr(default=None)

    def with_record(self, time, eta) -> "Gauge":
        """This gauge with its record (two float sequences; kept as read-only float64 arrays)."""
        import numpy as np
        out = self.model_copy()
        out._record = tuple(np.array(x, np.float64) for x in (time, eta))
        for array in out._record:
            array.flags.writeable = False
        return out

    @property
    def time(self):
        """s: the record's times, an array (None until Scene.with_gauges)."""
        return None if self._record is None else self._record[0]

    @property
    def eta(self):
        """The record's values (m, or m/m for a slope; None until Scene.with_gauges)."""
        return None if self._record is None else self._record[1]

    @property
    def variable(self) -> str:
        """The record's variable in a NetCDF file: ``eta``, ``slope_x`` or ``slope_y``."""
        return "eta" if self.quantity == "elevation" else self.quantity.replace("-", "_")


class GaugeWaves(_Section):
    """``type = "gauges"``: a directional linear sea reconstructed from elevation records at several
    gauges: one component per Fourier frequency of the records in ``omega_range`` and per direction
    of ``directions`` (deg, where the waves travel to), amplitudes and phases by a least-squares fit
    to all gauges at once (server/sea/gauges.py, docs/waves.md). ``start``: the records' time at
    simulation t = 0 (default: their first time); ``max_condition``: the largest condition number of
    a frequency's gauge-by-direction matrix accepted (the factor noise in the records is amplified by)."""
    type: Literal["gauges"]
    gauges: Annotated[list[Gauge], Field(min_length=1, max_length=64)]
    directions: Annotated[list[AngleDeg], Field(min_length=1, max_length=64)]
    omega_range: tuple[Frequency, Frequency] | None = None
    start: FileTime | None = None
    max_condition: Annotated[float, Field(ge=1.0, le=1e6, allow_inf_nan=False)] = 100.0
    ramp: RampTime = 0.0
    excitation: Excitation = "superposition"
    excitation_irf_duration: ExcitationIRFDuration = 20.0

    @model_validator(mode="after")
    def _distinct(self) -> "GaugeWaves":
        import numpy as np
        pos = np.array([[g.x, g.y] for g in self.gauges])
        for j in range(1, len(pos)):
            near = np.flatnonzero((np.hypot(*(pos[:j] - pos[j]).T) < 1e-3)
                                  & np.array([g.quantity == self.gauges[j].quantity for g in self.gauges[:j]]))
            if near.size:
                raise ValueError(f"gauges[{j}]: at ({pos[j][0]:g}, {pos[j][1]:g}) m, within 1 mm of gauges[{near[0]}] "
                                 f"and recording the same {self.gauges[j].quantity}: two such gauges add no "
                                 "information on direction (remove one)")
        heads = np.exp(1j * np.deg2rad(self.directions))
        for j in range(1, heads.size):
            same = np.flatnonzero(np.abs(heads[:j] - heads[j]) < 1e-9)
            if same.size:
                raise ValueError(f"directions[{j}]: {self.directions[j]:g} deg is directions[{same[0]}] again")
        if self.omega_range is not None and not self.omega_range[0] < self.omega_range[1]:
            raise ValueError(f"omega_range: [low, high] in rad/s with low < high (got {list(self.omega_range)})")
        return self

    @property
    def direction(self) -> float:
        """The first direction (deg): the sea's reference heading."""
        return self.directions[0]


Waves = Annotated[Union[StillWater, RegularWave, IrregularWave, ElevationWave, SeaState, ComponentWaves, GaugeWaves],
                  Field(discriminator="type")]


@dataclass(frozen=True)
class WavePeak:
    """A period a sea holds and its height, with the keys that set them: what the time step must
    resolve (clients/lockstep/preflight.py) and what must not break (server/model.py)."""
    period: float           # s: a regular wave's, a spectrum's peak period, a component's
    height: float           # m: its height, significant height (4 sqrt(m0)) or 2 a
    period_key: str
    height_key: str
    per_key: float = 1.0    # height / the value of height_key (2: a component's amplitude)


def _table_peak(system: WaveSystem, i: int) -> WavePeak:
    """A table spectrum's peak period (of S integrated over theta) and significant height."""
    import numpy as np
    w, d = np.asarray(system.omega, float), np.asarray(system.density, float)
    hz = system.units == "hz-deg"        # frequencies in Hz, density per Hz (and per degree)
    if d.ndim == 2:
        theta = np.asarray(system.theta, float)
        d = np.trapezoid(d, theta if hz else np.deg2rad(theta), axis=1)
    peak = float(w[int(np.argmax(d))])
    return WavePeak(period=1.0 / peak if hz else 2 * math.pi / peak, height=4.0 * math.sqrt(float(np.trapezoid(d, w))),
                    period_key=f"waves.systems[{i}].omega", height_key=f"waves.systems[{i}].density")


def wave_peaks(waves: Waves) -> list[WavePeak]:
    """The periods the scene's sea holds with their heights (none for still water and an elevation
    series): a regular wave's; an irregular sea's peak; each system's of a ``sea`` (a table's from its
    own values); each component of a ``components`` list."""
    if isinstance(waves, RegularWave):
        return [WavePeak(period=waves.period, height=waves.height, period_key="waves.period", height_key="waves.height")]
    if isinstance(waves, IrregularWave):
        return [WavePeak(period=waves.tp, height=waves.hs, period_key="waves.tp", height_key="waves.hs")]
    if isinstance(waves, SeaState):
        return [_table_peak(s, i) if s.spectrum == "table" else
                WavePeak(period=s.tp, height=s.hs, period_key=f"waves.systems[{i}].tp", height_key=f"waves.systems[{i}].hs")
                for i, s in enumerate(waves.systems)]
    if isinstance(waves, ComponentWaves):
        return [WavePeak(period=2 * math.pi / w, height=2.0 * a, period_key=f"waves.omega[{i}]",
                         height_key=f"waves.amplitude[{i}]", per_key=2.0)
                for i, (w, a) in enumerate(zip(waves.omega, waves.amplitude))]
    return []


Nonlinear = Literal["none", "hydrostatic", "froude-krylov"]
# second-order wave forces (server/terms/second_order.py): none, the mean drift, Newman's slow drift
# (T_ij = (T_ii + T_jj)/2) or the full difference QTF
SecondOrder = Literal["none", "mean-drift", "newman", "qtf"]


class Hydro(_Section):
    irf_duration: IRFDuration = 40.0
    interaction: Literal["full", "none"] = "full"   # body-to-body radiation blocks: all, or none
    # radiation memory (server/radiation/options.py, server/radiation/state_space.py, docs/radiation.md)
    radiation: Literal["convolution", "state-space", "constant", "off"] = "convolution"
    irf_taper: Fraction = 0.0  # cosine taper, fraction of irf_duration
    irf_domega: FrequencyStep | None = None  # resample B(w) (cubic)
    irf_tail: Literal["none", "asymptotic"] = "none"            # B(w) ~ c/w^n beyond the HDB grid
    irf_tail_cutoff: Frequency | None = None  # rad/s (default 3 w_max)
    ss_tolerance: Tolerance = 0.01
    ss_order: StateSpaceOrder | None = None  # fixed order per DOF pair (even)
    ss_max_order: StateSpaceOrder = 24
    ss_enforce_stability: bool = True
    coupling_tolerance: Fraction = 0.0
    # hydrostatics (and the incident wave's Froude-Krylov force) on the instantaneous wetted surface
    # of every wet body's hull (server/terms/nonlinear/term.py); a body's own ``nonlinear`` overrides it
    nonlinear: Nonlinear = "none"
    # the Froude-Krylov pressure and free surface on the hulls from the most energetic wave
    # components holding this fraction of the variance (1: all; the rest acts through the linear
    # excitation only; a setup warning names this key and what was left out)
    froude_krylov_energy: EnergyFraction = 1.0
    # second-order wave forces of every wet body (a body's own ``second_order`` overrides it);
    # ``drift_method``: which mean drift coefficients "mean-drift" and "newman" read (default: the
    # one method the HDB holds); ``sum_frequency``: add the sum-frequency QTF too
    second_order: SecondOrder = "none"
    drift_method: Literal["momentum", "control-surface", "pressure", "far-field"] | None = None
    sum_frequency: bool = False

    @model_validator(mode="after")
    def _orders(self) -> "Hydro":
        for key in ("ss_order", "ss_max_order"):
            v = getattr(self, key)
            if v is not None and v % 2:
                raise ValueError(f"{key}: must be even (poles come in complex-conjugate pairs), got {v}")
        return self



class Coupling(_Section):
    """How the multibody client (Exudyn or an FMU) and the force server exchange (README "Coupling
    schemes", docs/stability.md; clients/lockstep/coupling_schemes.py).

    scheme: "auto" (default) - "mass-matrix" when the client can take A_inf in its mass matrix (the
    Exudyn client always; an FMU when its added_mass parameters cover A_inf), else "implicit" when it
    can roll back, else the run is refused; "mass-matrix" - A_inf in the client's mass matrix (an
    FMU: as parameters), forces at t_k+1 from the predicted state; "explicit" - staggered: forces from the previous state held over the step and
    A_inf fed back as the lagged force -A_inf a_k (the classic added-mass instability: refused when
    the added-mass ratio exceeds ``explicit_limit``); "explicit-predictor" - the same lagged
    -A_inf a_k, forces at t_k+1 from the velocity-predicted state; "implicit" - -A_inf a_k+1 and the
    forces at the state the step ends in, iterated to ``tolerance`` with rollback (Exudyn state and
    the server's ``iteration``) and Aitken relaxation.

    exchange_every: the client takes this many steps of simulation.dt per exchange with the server
    (the server's step, setup.dt, is exchange_every * simulation.dt); between exchanges the forces
    are held (``between_exchanges = "hold"``) or varied linearly through the last two exchanged
    samples ("extrapolate")."""
    scheme: Literal["auto", "mass-matrix", "explicit", "explicit-predictor", "implicit"] = "auto"
    exchange_every: ExchangeSteps = 1
    between_exchanges: Literal["hold", "extrapolate"] = "hold"
    tolerance: Tolerance = 1e-8   # implicit: relative
    max_iterations: IterationCount = 50                    # implicit, per step
    explicit_limit: AddedMassRatio = 0.9  # max A_inf/m


class Steady(_Section):
    """``hydrolink steady``: periodic steady state in regular waves by pseudo-spectral collocation
    (Fourier series of ``order`` harmonics, collocated at 2 order + 1 points over one period, Newton
    on the nonlinear terms; clients/analysis/steady.py, docs/steady.md)."""
    order: HarmonicCount = 10
    formulation: Literal["dae", "ode"] = "dae"     # body coordinates + multipliers | null space of G
    tolerance: Tolerance = 1e-10  # Newton, relative residual
    max_iterations: IterationCount = 50
    # radiation at harmonic k: "hdb": A(kw), B(kw) of the HDB; "convolution": the A, B that the time
    # domain's truncated, sampled convolution realises (K(t) at dt over irf_duration)
    radiation: Literal["hdb", "convolution"] = "hdb"

class OptimizeLimit(_Section):
    """One ``[[optimize.limits]]`` entry: bounds on a PTO (``pto``: its force, stroke = extension from
    equilibrium, velocity) or on a body DOF (``body`` + ``dof``: its displacement, velocity)."""
    pto: str | None = None
    body: str | None = None
    dof: Literal["surge", "sway", "heave", "roll", "pitch", "yaw"] | None = None
    force: PositiveCoefficient | None = None          # N (N m for a rotary PTO axis)
    stroke: PositiveCoefficient | None = None         # m (rad)
    displacement: PositiveCoefficient | None = None   # m (rad), a body DOF from equilibrium
    velocity: PositiveCoefficient | None = None       # m/s (rad/s)

    @model_validator(mode="after")
    def _target(self) -> "OptimizeLimit":
        if (self.pto is None) == (self.body is None):
            raise ValueError("give pto (a PTO's limits) or body + dof (a body DOF's limits), one of them")
        if self.body is not None and self.dof is None:
            raise ValueError("dof: required with body")
        if self.pto is not None and (self.dof is not None or self.displacement is not None):
            raise ValueError("dof, displacement: for a body's limit (body = ...), not a PTO's (use stroke)")
        if self.body is not None and (self.force is not None or self.stroke is not None):
            raise ValueError("force, stroke: for a PTO's limit (pto = ...), not a body's")
        if all(getattr(self, k) is None for k in ("force", "stroke", "displacement", "velocity")):
            raise ValueError("no limit given: force, stroke, displacement or velocity")
        return self


class Optimize(_Section):
    """``hydrolink optimize``: the PTO force trajectory maximising the mean absorbed power over one
    wave period (regular) or repeat period (irregular), under ``limits``; clients/analysis/optimal/,
    docs/optimal-control.md. A PTO's ``force_limit``/``torque_limit`` is its force limit unless a
    limit entry gives one."""
    order: HarmonicCount | None = None              # default: [steady] order (regular waves)
    oversampling: Annotated[int, Field(ge=2, le=64)] = 8    # fine-grid points per collocation interval
    reactive: bool = True                           # false: no reactive power (P_pto(t) >= 0)
    efficiency: Efficiency = 1.0                    # PTO efficiency: electrical power eta P absorbing, P / eta fed back
    limits: list[OptimizeLimit] = []


Vector3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]
Vector6 = Annotated[list[Displacement], Field(min_length=6, max_length=6)]
Velocity6 = Annotated[list[Speed], Field(min_length=6, max_length=6)]
Coefficients6 = Annotated[list[Coefficient], Field(min_length=6, max_length=6)]
Matrix6 = Annotated[list[Coefficients6], Field(min_length=6, max_length=6)]
Inertia3 = Annotated[list[Coefficient], Field(min_length=3, max_length=3)]   # kg m^2


class Drag(_Section):
    """WEC-Sim's quadratic drag of a wet body, per DOF about its reference point:
    F_i = -1/2 rho cd_i area_i |u_i| u_i, u = v - (the undisturbed wave particle velocity plus the
    ``[current]`` at the reference point; rotational DOFs: none) when ``relative``, else u = v (the
    current is then ignored)."""
    cd: Annotated[list[FlowCoefficient], Field(min_length=6, max_length=6)]
    area: Annotated[list[Area], Field(min_length=6, max_length=6)]
    relative: bool = True


class NemohQTF(_Section):
    """``bodies[i].qtf``: NEMOH v3 QTF files added to the body's HDB (server/hdb/nemoh_qtf.py):
    ``difference`` (``OUT_QTFM_N*.dat``) and/or ``sum`` (``OUT_QTFP_N*.dat``), relative to the scene.
    The files record neither the unit of their frequency columns (Nemoh.cal's choice) nor the time
    convention of their complex values: both are stated here, required (never guessed)."""
    difference: Annotated[str, Field(min_length=1)] | None = None
    sum: Annotated[str, Field(min_length=1)] | None = None
    frequency_unit: Literal["rad/s", "Hz", "s"]
    convention: Literal["exp(-iwt)", "exp(+iwt)"]

    @model_validator(mode="after")
    def _some_file(self) -> "NemohQTF":
        if self.difference is None and self.sum is None:
            raise ValueError("difference: give the difference (OUT_QTFM_N*.dat) and/or the sum (OUT_QTFP_N*.dat) file")
        return self


class WamitRun(_Section):
    """``bodies[i].wamit``: what a WAMIT run's files do not state (server/hdb/wamit/run.py reads each
    from the ``.out``, else the ``.mmx``/``.pot``/``.frc``/``.cfg`` beside the ``.1``; a value a file
    states must agree). The run's, not the body's: the bodies of one HDB state the same table, or
    one of them states it. Lists: one entry per body of the run, in the run's order."""
    ulen: Length | None = None                                  # WAMIT's ULEN, m
    gravity: Gravity | None = None                              # the run's g
    depth: Union[Literal["inf"], Depth] | None = None           # the run's water depth (HBOT)
    xbody: Annotated[list[Vector3], Field(min_length=1)] | None = None   # each body's XBODY(1-3)
    vcg: Annotated[list[Coordinate], Field(min_length=1)] | None = None  # each body's VCG (body axes)
    volume: Annotated[list[Volume], Field(min_length=1)] | None = None   # displaced volumes (VCG != 0)
    iperout: Literal[1, 2, 3] | None = None     # first column: 1 period (s), 2 omega (rad/s), 3 omega^2 L/g


ModeName = Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")]
ModalValues = Annotated[list[Coefficient], Field(min_length=1)]


class BodyModes(_Section):
    """``bodies[i].modes``: the structure of the generalized (flexible) modes the body's HDB gives it
    beyond its six rigid DOFs (docs/generalized-modes.md): the modes by the HDB's names, and their
    modal mass, stiffness and damping, each a list (the diagonal, one value per name) or a table
    (one row per name) — or ``mmx``, a WAMIT ``.mmx`` whose external force matrices give them (the
    client reads it: :meth:`with_file`). The structure's coupling to the rigid DOFs is zero (free-free
    modes are orthogonal to the rigid motions); the hydrodynamic coupling comes from the HDB."""
    names: Annotated[list[ModeName], Field(min_length=1)]
    mass: list[ModalValues] | ModalValues | None = None      # kg (or kg m^2, per the mode's normalisation)
    stiffness: list[ModalValues] | ModalValues | None = None   # N/m; None: zero
    damping: list[ModalValues] | ModalValues | None = None     # N s/m; None: zero
    # the structure from a file instead (relative to the scene): a WAMIT .mmx's external force matrices
    # (IALTFRC = 2 or 3), numbered as the HDB's DOFs (each body's six, then its modes)
    mmx: Annotated[str, Field(min_length=1)] | None = None
    # the HDB build spec whose [[body.modes]] the HDB's modes are (relative to the scene; default the
    # body's hdb when it is one): their shapes on the hull, for the deformed mesh hydrolink view draws
    shapes: Annotated[str, Field(min_length=1)] | None = None
    initial_displacement: list[Displacement] | None = None     # each mode's coordinate at t = 0 (None: 0)
    # a PTO on each mode (a distributed PTO along a flexible body): a spring-damper on the modal
    # coordinate, one value per mode (0: none); its force and absorbed power are results variables
    pto_stiffness: ModalValues | None = None
    pto_damping: Annotated[list[NonNegativeCoefficient], Field(min_length=1)] | None = None
    _file: "ExternalMatrices | None" = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _square_and_positive(self) -> "BodyModes":
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"names: repeated mode in {self.names}")
        for key in ("initial_displacement", "pto_stiffness", "pto_damping"):   # one value per mode
            value = getattr(self, key)
            if value is not None and len(value) != len(self.names):
                raise ValueError(f"{key}: {len(value)} values for {len(self.names)} modes {self.names}: give one "
                                 "per mode (0 for a mode at rest or without a PTO)")
        if self.mmx is not None:
            given = [k for k in ("mass", "stiffness", "damping") if getattr(self, k) is not None]
            if given:
                raise ValueError(f"mmx: the structure comes from {self.mmx!r}, and {given} give(s) it too: "
                                 "give it either in the file or in mass, stiffness and damping")
            return self          # checked when the file's matrices come (with_file)
        if self.mass is None:
            raise ValueError("mass: required: each mode's modal mass (a list or a table), or mmx naming the "
                             "WAMIT .mmx whose external force matrices hold it")
        self._check_structure("{key}", "")
        return self

    def _check_structure(self, key: str, source: str) -> None:
        """Each matrix symmetric and the modal mass positive definite; ValueError naming ``key``
        (formatted with the matrix's name) and ``source`` (the file, or nothing)."""
        import numpy as np
        for name in ("mass", "stiffness", "damping"):
            m = self.matrix(name)
            if not np.allclose(m, m.T, rtol=1e-9, atol=0):
                raise ValueError(f"{key.format(key=name)}: {source}the modal {name} table must be symmetric")
        eig = np.linalg.eigvalsh(self.matrix("mass"))
        if eig.min() <= 1e-12 * max(abs(eig.max()), 1e-300):
            raise ValueError(f"{key.format(key='mass')}: {source}the modal mass must be positive definite (eigenvalues "
                             f"{np.round(eig, 6).tolist()}): a mode without mass has no dynamics; give each mode its "
                             "generalized mass")

    def with_file(self, block: "ExternalMatrices") -> "BodyModes":
        """These modes with ``mmx``'s matrices (the body's block, as the client read it); ValueError
        "mmx: why" when the block holds other modes than ``names``, couples the rigid DOFs and the
        modes, or is not a structure (unsymmetric, a modal mass not positive definite)."""
        if set(block.modes) != set(self.names):
            raise ValueError(f"mmx: {self.mmx}'s block of the body holds the modes {list(block.modes)}; names "
                             f"lists {self.names}")
        coupled = block.coupled()
        if coupled:
            raise ValueError(f"mmx: {self.mmx} couples the rigid DOFs and the modes in its external {', '.join(coupled)}: "
                             "the scene's modes hold no structural rigid-mode coupling (free-free modes have none); "
                             "give the modes' block in mass, stiffness and damping (the coupling then left out) "
                             "or remove it from the run")
        out = self.model_copy()
        out._file = block
        out._check_structure("mmx", f"{self.mmx}: ")
        return out

    @property
    def file_matrices(self) -> "ExternalMatrices | None":
        """The ``mmx`` file's block (None without ``mmx`` or until :meth:`with_file`)."""
        return self._file

    def matrix(self, key: str) -> "np.ndarray":
        """``mass``, ``stiffness`` or ``damping`` as an (n, n) array over ``names``; ValueError naming
        the key when its shape does not fit the names."""
        import numpy as np
        n, value = len(self.names), getattr(self, key)
        if self.mmx is not None:
            if self._file is None:
                raise ValueError(f"mmx: the matrices of {self.mmx!r} were not given (a client reads the file and "
                                 "sends it in hello.modal_structure)")
            return self._file.modal(key, self.names)
        if value is None:
            return np.zeros((n, n))
        if isinstance(value[0], list):
            m = np.asarray(value, float) if all(len(r) == n for r in value) else None
            if m is None or m.shape != (n, n):
                raise ValueError(f"{key}: a table of {len(value)} rows of {[len(r) for r in value]} values for "
                                 f"{n} modes {self.names}: give {n} rows of {n}, or a list of {n} values")
            return m
        if len(value) != n:
            raise ValueError(f"{key}: {len(value)} values for {n} modes {self.names}: give one per mode")
        return np.diag(np.asarray(value, float))

    def per_mode(self, key: str, names: "Collection[str]") -> list[float]:
        """A one-value-per-mode key (``initial_displacement``, ``pto_stiffness``, ``pto_damping``) in
        the order of ``names`` (the HDB's modes); 0 for each when not given."""
        value = getattr(self, key)
        return [0.0 if value is None else float(value[self.names.index(m)]) for m in names]

    def in_order(self, key: str, names: "Collection[str]") -> "np.ndarray":
        """:meth:`matrix` with its rows and columns in the order of ``names`` (the HDB's modes)."""
        import numpy as np
        order = [self.names.index(m) for m in names]
        return self.matrix(key)[np.ix_(order, order)]


class BodySections(_Section):
    """``bodies[i].sections``: the internal loads along the body's axis at ``stations`` (shear,
    bending, torsion: server/loads/sections.py, docs/generalized-modes.md "Loads along a body"),
    computed after the run from the HDB build's panel pressures and the mass distribution given
    here: segments of uniform mass per length between ``mass_stations`` (and point masses) on the
    line along ``axis`` through the body's centre of mass."""
    axis: Literal["x", "y", "z"] = "x"
    stations: Annotated[list[Coordinate], Field(min_length=1)]          # m along the axis (global frame at rest)
    mass_stations: Annotated[list[Coordinate], Field(min_length=2)]     # m: the segments' edges, increasing
    mass_per_length: Annotated[list[LineDensity], Field(min_length=1)]  # kg/m, one per segment
    # kg m^2/m: each segment's own rotary inertia per length about its centroid, about x, y, z (None: 0)
    section_inertia: list[Annotated[list[NonNegativeCoefficient], Field(min_length=3, max_length=3)]] | None = None
    point_masses: list[Annotated[list[float], Field(min_length=2, max_length=2)]] = []   # [position, kg]

    @model_validator(mode="after")
    def _segments(self) -> "BodySections":
        edges = self.mass_stations
        if any(b <= a for a, b in zip(edges, edges[1:])):
            raise ValueError("mass_stations: must be strictly increasing (the edges of the mass segments)")
        if len(self.mass_per_length) != len(edges) - 1:
            raise ValueError(f"mass_per_length: {len(self.mass_per_length)} values for {len(edges) - 1} segments "
                             "between mass_stations: give one per segment")
        if self.section_inertia is not None and len(self.section_inertia) != len(edges) - 1:
            raise ValueError(f"section_inertia: {len(self.section_inertia)} rows for {len(edges) - 1} segments")
        if any(b <= a for a, b in zip(self.stations, self.stations[1:])):
            raise ValueError("stations: must be strictly increasing")
        for j, (at, m) in enumerate(self.point_masses):
            if not (math.isfinite(m) and m > 0 and math.isfinite(at)):
                raise ValueError(f"point_masses[{j}]: [position, mass] with a finite position and a mass > 0")
        return self


class HydroState(_Section):
    """One more hydrodynamic state of a body (``[[bodies.hydro_states]]``): its name and its HDB (a
    draft, a ballast case, an operating mode; server/hydro_states.py). The body's own ``hdb`` is the
    state named ``hydro_state``, the one it starts in."""
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")]
    hdb: Annotated[str, Field(min_length=1)]


class HydroSwitch(_Section):
    """A scene rule that switches a body's hydrodynamic state (``[[hydro_switches]]``): at ``time``
    (once, at the first step with t >= time), or at every step where the body's ``dof`` displacement
    from equilibrium (m, rad; the position the client sends) is ``below`` or ``above`` a value.
    Rules are read in scene order each step from the first step after t = 0; the last that fires wins."""
    body: Annotated[str, Field(min_length=1)]
    state: Annotated[str, Field(min_length=1)]
    time: Duration | None = None
    dof: Literal["surge", "sway", "heave", "roll", "pitch", "yaw"] | None = None
    below: Displacement | None = None
    above: Displacement | None = None

    @model_validator(mode="after")
    def _one_trigger(self) -> "HydroSwitch":
        level = self.below is not None or self.above is not None
        if self.time is not None and (level or self.dof is not None):
            raise ValueError("time: a rule switches at a time or on a threshold (dof with below/above), not both")
        if self.time is None and not (self.dof is not None and level):
            raise ValueError("time: give the time of the switch, or dof with below or above (a threshold)")
        if self.below is not None and self.above is not None:
            raise ValueError("below: give below or above, not both (two rules make a band with hysteresis)")
        return self


class Body(_Section):
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")]
    hdb: Annotated[str, Field(min_length=1)] | None = None   # None: a dry body (no hydrodynamics)
    hdb_body: str | None = None
    # the time convention of a Capytaine-layout HDB file's complex amplitudes when the file does not
    # declare it (default Capytaine's "exp(-iwt)"; WecOptTool writes "exp(+iwt)")
    hdb_convention: Literal["exp(-iwt)", "exp(+iwt)"] | None = None
    # a WAMIT run's facts its files do not state (XBODY, ULEN, g, depth, VCG, volume, IPEROUT)
    wamit: WamitRun | None = None
    mass: Mass
    # global frame at equilibrium; not needed by a wet body whose rotations are all locked (it
    # then sits at its HDB reference point, where the forces act)
    center_of_mass: Vector3 | None = None
    # about the centre of mass, global axes: principal moments or a 3x3 matrix; not needed (and
    # then unused) when the body's rotations are all locked (dofs without roll, pitch and yaw)
    inertia: Union[Inertia3, Annotated[list[Inertia3], Field(min_length=3, max_length=3)], None] = None
    dofs: list[Literal["surge", "sway", "heave", "roll", "pitch", "yaw"]] = list(DOF_NAMES)
    initial_displacement: Vector6 = [0.0] * 6
    initial_velocity: Velocity6 = [0.0] * 6
    # wet bodies: additional damping about the reference point, body DOF order (HydroDyn's AddBLin,
    # AddBQuad): F = -B_lin v - B_quad (v |v|), absolute velocity; 6 values (diagonal) or a 6x6 table
    linear_damping: Coefficients6 | Matrix6 | None = None
    quadratic_damping: Coefficients6 | Matrix6 | None = None
    drag: Drag | None = None
    # wet bodies: nonlinear hydrostatics / Froude-Krylov for this body (default: [hydro] nonlinear)
    # and its closed hull, freeboard included (a mesh file Capytaine reads, global frame at
    # equilibrium; default: the hull of the body's HDB build spec); also what `hydrolink view` draws
    nonlinear: Nonlinear | None = None
    mesh: Annotated[str, Field(min_length=1)] | None = None
    # wet bodies: second-order wave forces of this body (default: [hydro] second_order)
    second_order: SecondOrder | None = None
    # wet bodies: NEMOH QTF files added to the body's HDB (every body of that HDB gets them)
    qtf: NemohQTF | None = None
    # wet bodies: the HDB's headings completed by mirror images (server/sea/headings.py) for a body
    # symmetric about the plane y = 0 ("xz"), x = 0 ("yz") or both: a half range serves every heading
    heading_symmetry: Literal["none", "xz", "yz", "both"] = "none"
    # wet bodies: the excitation evaluated each step at every wave's direction relative to the body's
    # instantaneous yaw, rotated into the global frame (server/sea/passive_yaw.py; WEC-Sim's option)
    passive_yaw: bool = False
    # s: the waves are read at the yaw low-passed with this time constant (the body's slow heading, the
    # wave-frequency yaw left out; 0: the instantaneous yaw, WEC-Sim's)
    passive_yaw_filter: RampTime = 0.0
    # "initial-heading": added mass, damping and hydrostatic stiffness stay the initial heading's while
    # the excitation turns (the only choice; stating it acknowledges it for a body not symmetric about
    # its yaw axis, which gets a setup warning otherwise)
    passive_yaw_coefficients: Literal["initial-heading"] | None = None
    # wet bodies whose HDB has generalized modes: their modal mass, stiffness and damping (issue 38)
    modes: BodyModes | None = None
    # wet bodies: the internal loads along the body's axis after the run (structural design) and the
    # linear pressure on every hull panel over the run (its own file beside the results), both from the
    # HDB build's panel pressures: the file the build named (hdb build ``panel_pressures = true``), or this one
    sections: BodySections | None = None
    pressure_output: bool = False
    panel_pressures: Annotated[str, Field(min_length=1)] | None = None
    # wet bodies: variable hydrodynamics (server/hydro_states.py): the state ``hdb`` is (its name) and the
    # body's other states, each its own HDB, switched by [[hydro_switches]]; the radiation memory across a
    # switch: "current-kernel" (default; the state's IRF over the whole velocity history, WEC-Sim's default)
    # or "kernel-at-emission" (each velocity sample with the IRF of the state it was sent in, WEC-Sim #1411)
    hydro_state: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")] | None = None
    hydro_states: list[HydroState] = []
    hydro_memory: Literal["current-kernel", "kernel-at-emission"] | None = None
    # dry bodies only: the node's position (default: the centre of mass) and a constant buoyancy
    reference_point: Vector3 | None = None
    buoyancy_volume: Volume = 0.0
    center_of_buoyancy: Vector3 | None = None

    @model_validator(mode="after")
    def _symmetry_of_an_hdb(self) -> "Body":
        if self.heading_symmetry != "none" and self.hdb is None:
            raise ValueError("heading_symmetry: only for a wet body (it completes the headings of its hdb)")
        if self.passive_yaw and self.hdb is None:
            raise ValueError("passive_yaw: only for a wet body (it turns the excitation of its hdb)")
        for key in ("passive_yaw_filter", "passive_yaw_coefficients"):
            if getattr(self, key) and not self.passive_yaw:
                raise ValueError(f"{key}: only with passive_yaw = true")
        if self.passive_yaw and "yaw" not in self.dofs:
            raise ValueError(f"passive_yaw: needs the body's yaw DOF free (dofs {self.dofs} lock yaw): a body "
                             "that cannot turn keeps its heading; add \"yaw\" to dofs or drop passive_yaw")
        return self

    @model_validator(mode="after")
    def _hydro_states_of_a_wet_body(self) -> "Body":
        if self.hydro_states and self.hdb is None:
            raise ValueError("hydro_states: only for a wet body (each state is an HDB beside its hdb)")
        if self.hydro_states and self.hydro_state is None:
            raise ValueError("hydro_state: required with hydro_states: the name of the state the body's hdb is "
                             "(the state it starts in)")
        for key in ("hydro_state", "hydro_memory"):
            if getattr(self, key) is not None and not self.hydro_states:
                raise ValueError(f"{key}: only with hydro_states (a body with one HDB has one state)")
        for key in ("sections", "pressure_output", "panel_pressures"):
            if getattr(self, key) not in (None, False) and self.hdb is None:
                raise ValueError(f"{key}: only for a wet body (from its HDB build's panel pressures)")
            if getattr(self, key) not in (None, False) and self.modes is not None:
                raise ValueError(f"{key}: not with modes: the loads and pressures of a flexible body need its "
                                 "deformation along the hull and its structural model, not built")
        if self.hydro_states and self.modes is not None:
            raise ValueError("hydro_states: not with modes: a switch replaces the rigid DOFs' A-infinity and "
                             "stiffness only, and how a state's modes would carry over is not modelled (give the "
                             "flexible body one HDB)")
        names = [self.hydro_state] + [s.name for s in self.hydro_states]
        for j, n in enumerate(names[1:]):
            if n in names[:j + 1]:
                raise ValueError(f"hydro_states[{j}].name: duplicate state name {n!r}")
        return self

    def state_names(self) -> list[str]:
        """The body's hydrodynamic states, the one its ``hdb`` is first (empty: one HDB, no states)."""
        return [self.hydro_state] + [s.name for s in self.hydro_states] if self.hydro_states else []

    @model_validator(mode="after")
    def _inertia_if_it_rotates(self) -> "Body":
        turning = [d for d in ("roll", "pitch", "yaw") if d in self.dofs]
        if self.inertia is None and turning:
            raise ValueError(f"inertia: required: the body's rotational DOFs {turning} are active (a body that "
                             "only translates needs none)")
        if self.center_of_mass is None and turning:
            raise ValueError(f"center_of_mass: required: the body's rotational DOFs {turning} are active (a wet "
                             "body that only translates needs none)")
        if self.center_of_mass is None and self.hdb is None:
            raise ValueError("center_of_mass: required for a dry body (it places the body)")
        return self

    def dry_node(self) -> "np.ndarray":
        """A body without an HDB: its node's position, ``reference_point``, default the centre of
        mass (where the client puts it, and a Morison-only body's forces refer to)."""
        import numpy as np
        return np.asarray(self.reference_point if self.reference_point is not None else self.center_of_mass, float)

    def com_or(self, reference) -> "np.ndarray":
        """The centre of mass, or for a wet body that gives none (its rotations all locked) the
        ``reference`` point it sits at (its HDB reference point, the body's node)."""
        import numpy as np
        return np.asarray(reference if self.center_of_mass is None else self.center_of_mass, float).reshape(3)

    @model_validator(mode="after")
    def _second_order_if_wet(self) -> "Body":
        if self.hdb is None and self.second_order not in (None, "none"):
            raise ValueError("second_order: only for a wet body (with hdb): the coefficients come from its HDB")
        if self.hdb is None and self.qtf is not None:
            raise ValueError("qtf: only for a wet body (with hdb): the QTF is added to its HDB")
        return self

    @model_validator(mode="after")
    def _dry_only_keys(self) -> "Body":
        if self.hdb is not None:
            for key in ("reference_point", "center_of_buoyancy"):
                if getattr(self, key) is not None:
                    raise ValueError(f"{key}: only for a dry body (without hdb): a wet body's reference "
                                     "point and buoyancy come from its HDB")
            if self.buoyancy_volume:
                raise ValueError("buoyancy_volume: only for a dry body (without hdb)")
            if self.hdb_body is not None and not self.hdb_body:
                raise ValueError("hdb_body: must not be empty")
        elif self.hdb_body is not None:
            raise ValueError("hdb_body: needs hdb")
        elif self.hdb_convention is not None:
            raise ValueError("hdb_convention: needs hdb")
        elif self.wamit is not None:
            raise ValueError("wamit: needs hdb (the WAMIT run's files)")
        for key in ("drag", "nonlinear", "mesh", "modes"):
            if getattr(self, key) is not None and self.hdb is None:
                raise ValueError(f"{key}: only for a wet body (with hdb): the force server applies it")
        for key in ("linear_damping", "quadratic_damping"):
            value = getattr(self, key)
            if value is None:
                continue
            if self.hdb is None:
                raise ValueError(f"{key}: only for a wet body (with hdb): the force server applies it")
            import numpy as np
            m = np.diag(value) if not isinstance(value[0], list) else np.asarray(value, float)
            if np.any(np.diag(m) < 0):
                raise ValueError(f"{key}: the diagonal must be >= 0 (got {np.diag(m).tolist()})")
        return self

    @property
    def viscous(self) -> bool:
        """True when the body has a viscous term (linear or quadratic damping, drag)."""
        return self.linear_damping is not None or self.quadratic_damping is not None or self.drag is not None

    def damping_matrix(self, key: str):
        """``linear_damping`` or ``quadratic_damping`` as a 6x6 array (None when not given)."""
        import numpy as np
        value = getattr(self, key)
        if value is None:
            return None
        return np.diag(np.asarray(value, float)) if not isinstance(value[0], list) else np.asarray(value, float)


    @property
    def wet(self) -> bool:
        return self.hdb is not None

    @field_validator("dofs")
    @classmethod
    def _unique_dofs(cls, v: list[str]) -> list[str]:
        if not v:
            raise ValueError("needs at least one DOF")
        if len(set(v)) != len(v):
            raise ValueError(f"repeated DOF in {v}")
        return v

    @field_validator("inertia")
    @classmethod
    def _inertia_valid(cls, v):
        import numpy as np
        if v is None:
            return v
        m = np.diag(v) if len(v) == 3 and not isinstance(v[0], list) else np.asarray(v, float)
        if not np.allclose(m, m.T, rtol=1e-9, atol=0):
            raise ValueError("3x3 inertia must be symmetric")
        if np.any(np.linalg.eigvalsh(m) <= 0):
            raise ValueError("inertia must be positive definite (all principal moments > 0)")
        return v

    @property
    def inertia_matrix(self):
        """The 3x3 inertia; for a body whose rotations are all locked and that gives none,
        mass x (1 m)^2 isotropic: a well-conditioned value that never enters its motion."""
        import numpy as np
        v = self.inertia
        if v is None:
            return np.eye(3) * float(self.mass)
        return np.diag(v).astype(float) if not isinstance(v[0], list) else np.asarray(v, float)

    @property
    def active_mask(self) -> list[bool]:
        return [d in self.dofs for d in DOF_NAMES]

    @property
    def hdb_body_name(self) -> str:
        return self.hdb_body or self.name


Name = Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")]
UnitVector = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]
JOINT_TYPES = ("fixed", "spherical", "revolute", "prismatic", "universal", "cylindrical", "planar")


def _unit(v: list[float], key: str) -> list[float]:
    n = math.sqrt(sum(x * x for x in v))
    if n < 1e-12:
        raise ValueError(f"{key}: must be a non-zero vector")
    return [x / n for x in v]


class PointMass(_Section):
    """A 3-DOF point mass (e.g. a rope connection point); dry, with optional constant buoyancy."""
    name: Name
    mass: Mass
    position: Vector3
    initial_velocity: Annotated[list[Speed], Field(min_length=3, max_length=3)] = [0.0, 0.0, 0.0]
    buoyancy_volume: Volume = 0.0


class Friction(_Section):
    """Regularised Coulomb friction on a joint's free relative motion (force or torque)."""
    force: PositiveCoefficient           # Coulomb level, N (prismatic) or N m (revolute)
    velocity: RegularisationSpeed = 1e-3  # regularisation velocity: friction = force * tanh(v / velocity)


class Joint(_Section):
    """A kinematic joint between two bodies (or a body and "ground") at a point, global frame at t=0.

    axis: revolute/prismatic/cylindrical - the free axis; planar - the plane normal; universal - the
    first free axis (fixed in body1); axis2: universal - the second free axis (fixed in body2,
    perpendicular to axis)."""
    name: Name | None = None
    type: Literal["fixed", "spherical", "revolute", "prismatic", "universal", "cylindrical", "planar"]
    body1: Name
    body2: Name
    point: Vector3
    axis: UnitVector | None = None
    axis2: UnitVector | None = None
    friction: Friction | None = None

    @model_validator(mode="after")
    def _axes(self) -> "Joint":
        needs_axis = self.type in ("revolute", "prismatic", "universal", "cylindrical", "planar")
        if needs_axis and self.axis is None:
            raise ValueError(f"axis: required for a {self.type} joint")
        if not needs_axis and self.axis is not None:
            raise ValueError(f"axis: not used by a {self.type} joint")
        if self.type == "universal":
            if self.axis2 is None:
                raise ValueError("axis2: required for a universal joint")
            a, b = _unit(self.axis, "axis"), _unit(self.axis2, "axis2")
            if abs(sum(x * y for x, y in zip(a, b))) > 1e-6:
                raise ValueError("axis2: must be perpendicular to axis")
        elif self.axis2 is not None:
            raise ValueError(f"axis2: only for a universal joint, not {self.type}")
        if self.axis is not None:
            _unit(self.axis, "axis")
        if self.friction is not None and self.type not in ("revolute", "prismatic"):
            raise ValueError(f"friction: offered for revolute and prismatic joints, not {self.type}")
        if self.body1 == self.body2:
            raise ValueError(f"body2: a joint needs two different bodies (both are {self.body1!r})")
        return self

    def freed_dofs(self) -> tuple[int, ...] | None:
        """The global DOFs (0-5) whose velocity this joint leaves free to the body it joins to one
        that does not move: a revolute about coordinate axis k, the two translations across k and the
        rotation about k (its point need not be the body's reference point); a prismatic along k,
        translation k. None where it frees a mix of them (an oblique axis) or is of another type."""
        if self.type not in ("revolute", "prismatic") or self.axis is None:
            return None
        axis = [abs(float(x)) for x in self.axis]
        k = axis.index(max(axis))
        if axis[k] != 1.0 or sum(axis) != 1.0:
            return None
        return tuple(d for d in range(3) if d != k) + (3 + k,) if self.type == "revolute" else (k,)


class Constraint(_Section):
    """Fix one DOF of a body (to ground): its position (displacement from equilibrium) or velocity."""
    body: Name
    dof: Literal["surge", "sway", "heave", "roll", "pitch", "yaw"]
    type: Literal["position", "velocity"] = "position"
    value: Displacement = 0.0


class LinearPTO(_Section):
    """A spring-damper along the line between point1 (on body1) and point2 (on body2 or ground); to
    ground it may instead act along a fixed global ``direction`` from point1 (no anchor point to
    invent: a heave PTO is ``direction = [0, 0, -1]``), exactly, whatever the body's motion."""
    name: Name
    type: Literal["linear"]
    body1: Name
    point1: Vector3
    body2: Name
    point2: Vector3 | None = None
    direction: UnitVector | None = None         # to ground: along a global axis, e.g. [0, 0, -1]
    # may be negative: a reactive controller's tuning below resonance commands a negative spring
    # (the plant stays stable while the hydrostatic stiffness exceeds it; hydrolink steady/optimize)
    stiffness: Coefficient = 0.0
    damping: NonNegativeCoefficient = 0.0
    rest_length: NonNegativeLength | None = None      # default: the initial distance (no preload)
    force_limit: PositiveCoefficient | None = None

    @model_validator(mode="after")
    def _point_or_direction(self) -> "LinearPTO":
        if (self.point2 is None) == (self.direction is None):
            raise ValueError("point2 or direction: give one (direction: a PTO to ground along a fixed axis)")
        if self.direction is not None:
            if self.body2 != "ground":
                raise ValueError(f"direction: only for a PTO to ground (body2 = \"ground\", not {self.body2!r})")
            e = _unit(self.direction, "direction")
            if sorted(abs(x) for x in e) != [0.0, 0.0, 1.0]:
                raise ValueError(f"direction: along a global axis, e.g. [0, 0, -1] (got {self.direction}); for "
                                 "another direction give point2")
            for key in ("rest_length", "force_limit"):
                if getattr(self, key) is not None:
                    raise ValueError(f"{key}: not with direction (give point2)")
        return self

    @property
    def unit_direction(self) -> list[float] | None:
        """``direction`` normalised (None for a PTO given by point2)."""
        return None if self.direction is None else _unit(self.direction, "direction")


RotaryAxis = Literal["roll", "pitch", "yaw"]


class RotaryPTO(_Section):
    """Spring-damper on relative rotations of body2 w.r.t. body1 about chosen axes of a frame at point
    (default: the global axes at t=0). Often on top of a spherical joint (penalty form)."""
    name: Name
    type: Literal["rotary"]
    body1: Name
    body2: Name
    point: Vector3
    axes: Annotated[list[RotaryAxis], Field(min_length=1, max_length=3)]
    frame: Annotated[list[UnitVector], Field(min_length=3, max_length=3)] | None = None
    stiffness: Union[Coefficient, Annotated[list[Coefficient], Field(min_length=1, max_length=3)]] = 0.0   # < 0: reactive
    damping: Union[NonNegativeCoefficient, Annotated[list[NonNegativeCoefficient], Field(min_length=1, max_length=3)]] = 0.0
    torque_limit: PositiveCoefficient | None = None

    @model_validator(mode="after")
    def _per_axis(self) -> "RotaryPTO":
        if len(set(self.axes)) != len(self.axes):
            raise ValueError(f"axes: repeated axis in {self.axes}")
        for key in ("stiffness", "damping"):
            v = getattr(self, key)
            if isinstance(v, list) and len(v) != len(self.axes):
                raise ValueError(f"{key}: one value per axis ({len(self.axes)}), got {len(v)}")
        return self


PTO = Annotated[Union[LinearPTO, RotaryPTO], Field(discriminator="type")]



class LinearMooring(_Section):
    """6x6 linear stiffness/damping of a body about a point (global, at t=0), plus a constant
    pretension (force and moment about the point, in the global frame)."""
    name: Name | None = None
    type: Literal["linear"]
    body: Name
    point: Vector3
    stiffness: Union[Coefficients6, Matrix6] = [0.0] * 6    # diagonal, or a 6x6 table
    damping: Union[Coefficients6, Matrix6] = [0.0] * 6
    pretension: Coefficients6 = [0.0] * 6


class RopeMooring(_Section):
    """A 3D rope (Exudyn cable elements) from an anchor to an attachment on a body or point mass.

    anchor: a fixed point (ground; on the seabed when its z equals minus the water depth); attach_to a
    body (at point, global at t=0) or a point mass (point optional)."""
    name: Name | None = None
    type: Literal["rope"]
    anchor: Vector3
    attach_to: Name
    point: Vector3 | None = None
    length: Length                       # unstretched
    axial_stiffness: PositiveCoefficient  # EA, N
    mass_per_length: LineDensity         # kg/m (in water: submerged weight is computed with the
    diameter: NonNegativeDiameter = 0.0  #  displaced volume pi d^2/4 per metre)
    elements: CableElements = 10
    bending_stiffness: NonNegativeCoefficient = 0.0  # EI, N m^2 (0: a small value for numerical robustness)
    seabed: bool = True                   # contact with a flat seabed at z = -depth (finite depth)


class MoorDynMooring(_Section):
    """A MoorDyn v2 mooring system (lumped-mass lines with seabed contact): its own input ``file``
    (relative to the scene) holds the lines, its time step dtM, initial-condition and output
    options; hydrolink steps it every multibody step (clients/exudyn/moordyn_mooring.py).

    bodies: the scene bodies driving the file's coupled bodies, in the file's order (pose = the scene
    body's reference point and Tait-Bryan xyz angles; the file's points on a coupled body are
    relative to that reference point); points: the scene body each of the file's coupled points is
    fixed to, in the file's order (where the file puts the point at t = 0 is where it sits on that
    body). record_nodes: line node positions in the results (time, line, node, xyz). static_offset:
    estimate the bodies' equilibrium offset under the mooring at t = 0 (their restoring force
    against the mooring's load; reported, the run still starts where the scene says). workers: 0
    steps MoorDyn in the run's process; N >= 1 in N worker processes (default 1: the whole file in
    one, the same results to the bit), the file's independent groups of lines spread over them,
    stepped while the run computes the hydrodynamic forces (clients/exudyn/moordyn_split.py,
    moordyn_workers.py; a file that cannot be split is refused with the reason)."""
    name: Name
    type: Literal["moordyn"]
    file: Annotated[str, Field(min_length=1)]
    bodies: list[Name] = []
    points: list[Name] = []
    record_nodes: bool = False
    # estimate the coupled bodies' static offset under the mooring's pretension at t = 0 (reported
    # in the run summary and the results' moordyn attribute; costs 1 + DOFs + iterations MoorDyn
    # initial-condition solves)
    static_offset: bool = True
    # MoorDyn in this many worker processes (0: in the run's process); 1 by measurement (RM3 on
    # SEA-Stack's file, five bodies: RTF 6.5 -> 9.1 and 6.8 -> 10.6 at load 4-8, bench_moordyn_workers.py)
    workers: Annotated[int, Field(ge=0, le=64)] = 1

    @model_validator(mode="after")
    def _coupled(self) -> "MoorDynMooring":
        # (".bodies": relative to the mooring, not the scene's bodies)
        if not self.bodies and not self.points:
            raise ValueError(".bodies: a MoorDyn mooring needs at least one coupled scene body (bodies or points)")
        if len(set(self.bodies)) != len(self.bodies):
            raise ValueError(f".bodies: repeated body in {self.bodies} (one scene body per coupled MoorDyn body)")
        return self

    @property
    def coupled_bodies(self) -> list[str]:
        """Every scene body the mooring acts on, first appearance order (its rows in mooring_force)."""
        return list(dict.fromkeys([*self.bodies, *self.points]))


Mooring = Annotated[Union[LinearMooring, RopeMooring, MoorDynMooring], Field(discriminator="type")]


class MorisonElement(_Section):
    """A slender cylindrical member on a wet body, from ``point_a`` to ``point_b`` (global frame at
    equilibrium): Morison's equation in relative form on each of its ``segments``, over its wetted
    part (below the still water line), with the undisturbed wave's kinematics (u: plus the
    ``[current]``) at the segment's mean position:
    f = rho (1 + ca) V a_n + 1/2 rho cd D L |u_n - v_n| (u_n - v_n) per segment (n:
    normal to the member), the member's added mass rho ca V in the body's mass matrix (SPEC §5.1
    setup.added_mass); forces and moments about the body's reference point."""
    name: Name | None = None
    body: Name
    point_a: Vector3
    point_b: Vector3
    diameter: Diameter
    cd: FlowCoefficient
    ca: FlowCoefficient = 1.0
    segments: SegmentCount = 20

    @model_validator(mode="after")
    def _length(self) -> "MorisonElement":
        if math.dist(self.point_a, self.point_b) < 1e-9:
            raise ValueError("point_b: must differ from point_a (a member has a length)")
        return self


DofName = Literal["surge", "sway", "heave", "roll", "pitch", "yaw"]
FMUVariable = Annotated[str, Field(min_length=1)]


class FMUBodyMap(_Section):
    """FMU variables of one body, keyed by DOF: outputs position/velocity (per active DOF), inputs
    force (the sum) or excitation/radiation/hydrostatic (components); parameters that receive A∞ and
    the hydrostatic stiffness, keyed "heave" (diagonal) or "surge,pitch" (an off-diagonal entry)."""
    position: dict[DofName, FMUVariable] = {}
    velocity: dict[DofName, FMUVariable] = {}
    force: dict[DofName, FMUVariable] = {}
    excitation: dict[DofName, FMUVariable] = {}
    radiation: dict[DofName, FMUVariable] = {}
    hydrostatic: dict[DofName, FMUVariable] = {}
    added_mass: dict[str, FMUVariable] = {}
    hydrostatic_stiffness: dict[str, FMUVariable] = {}

    @field_validator("added_mass", "hydrostatic_stiffness")
    @classmethod
    def _dof_pairs(cls, v: dict[str, str]) -> dict[str, str]:
        for key in v:
            if not all(d in DOF_NAMES for d in key.split(",")) or key.count(",") > 1:
                raise ValueError(f"key {key!r}: a DOF (\"heave\") or two DOFs (\"surge,pitch\")")
        return v


#: the deprecated [client.coupling] mode of an FMU client -> [coupling] scheme
MODE_SCHEME = {"auto": "auto", "parameters": "mass-matrix", "iterative": "implicit", "explicit": "explicit-predictor"}


class FMUCoupling(_Section):
    """Deprecated: ``[client.coupling]`` of an FMU client, read as ``[coupling]`` (MODE_SCHEME)."""
    mode: Literal["auto", "parameters", "iterative", "explicit"] = "auto"
    tolerance: Tolerance = 1e-6                          # relative interface-force residual
    max_iterations: IterationCount = 50
    explicit_limit: ExplicitSpectralRadius = 0.5   # max spectral radius of M⁻¹A∞


class ExudynClient(_Section):
    """The Exudyn multibody client. ``reduce``: bodies whose locked DOFs need no rigid-body node are
    built with their active coordinates only, and bodies held to ground by a fixed joint are left out
    of the integrated system (clients/exudyn/mechanism.py, "Reduced bodies", "Held bodies"); false keeps
    every body a 6-DOF rigid body with its locked DOFs as coordinate constraints."""
    type: Literal["exudyn"]
    reduce: bool = True


class FMUClient(_Section):
    """A co-simulation FMU (FMI 2.0 or 3.0) as the multibody client; it owns the whole mechanism."""
    type: Literal["fmu"]
    fmu: Annotated[str, Field(min_length=1)]                 # relative to the scene file
    communication_step: TimeStep | None = None               # default simulation.dt; must divide it
    positions: Literal["displacement", "absolute"] = "displacement"   # FMU position outputs
    parameters: dict[str, Union[bool, ParameterInt, ParameterFloat, str]] = {}
    coupling: FMUCoupling | None = None                      # deprecated: [coupling]
    bodies: dict[str, FMUBodyMap]

    def check(self, scene: "Scene") -> None:
        """Cross-checks against the scene's bodies (the first problem as 'key: why')."""
        for key in ("point_masses", "joints", "constraints", "ptos", "moorings"):
            if getattr(scene, key):
                raise ValueError(f"{key}: the FMU client owns the mechanism (model it inside the FMU), "
                                 f"so [client] type = \"fmu\" takes no {key}")
        wet = {b.name: b for b in scene.bodies if b.wet}
        for i, b in enumerate(scene.bodies):
            if not b.wet:
                raise ValueError(f"bodies[{i}].hdb: the FMU client couples wet bodies only")
            if b.name not in self.bodies:
                raise ValueError(f"client.bodies: no mapping for body {b.name!r}")
        for name, m in self.bodies.items():
            if name not in wet:
                raise ValueError(f"client.bodies.{name}: no body named {name!r} (known: {sorted(wet)})")
            for d in wet[name].dofs:
                for key in ("position", "velocity"):
                    if d not in getattr(m, key):
                        raise ValueError(f"client.bodies.{name}.{key}: no FMU variable for active DOF {d!r}")
                if d not in m.force and d not in m.excitation and d not in m.radiation:
                    raise ValueError(f"client.bodies.{name}.force: no FMU input for active DOF {d!r}")
            for key in ("position", "velocity", "force", "excitation", "radiation", "hydrostatic"):
                for d in getattr(m, key):
                    if d not in wet[name].dofs:
                        raise ValueError(f"client.bodies.{name}.{key}.{d}: not an active DOF of {name!r}")
                    if key in ("excitation", "radiation", "hydrostatic") and d in m.force:
                        raise ValueError(f"client.bodies.{name}.{key}.{d}: {d} already has a force input")


Client = Annotated[Union[ExudynClient, FMUClient], Field(discriminator="type")]


MEASUREMENTS = ("body_position", "body_velocity", "pto_displacement", "pto_velocity", "pto_force",
                "wave_elevation")


class Controller(_Section):
    """An external controller (its own process, over the server; SPEC §5.7) driving linear PTOs.

    Every ``period`` (a multiple of dt) it receives the measurements of the state at t_k and returns
    commands — added PTO forces (``command = "force"``) or damping/stiffness setpoints
    (``"impedance"``) — which act from step k + ``latency`` (1: over t_k -> t_k+1) until the next
    command. A command missing ``timeout`` seconds after its measurements were relayed, or
    malformed, is replaced by the ``fallback``: "hold" (keep what is in force) or "passive" (added
    force 0, damping ``fallback_damping`` — default the PTO's scene damping — and the scene stiffness)."""
    name: Name
    ptos: Annotated[list[Name], Field(min_length=1)]
    period: Duration | None = None                       # s; default simulation.dt
    command: Literal["force", "impedance"] = "force"
    measurements: list[Literal["body_position", "body_velocity", "pto_displacement", "pto_velocity",
                               "pto_force", "wave_elevation"]] = ["pto_displacement", "pto_velocity", "pto_force"]
    bodies: list[Name] | None = None                     # for body_*; default every scene body
    wave_points: Annotated[list[Annotated[list[Coordinate], Field(min_length=2, max_length=2)]],
                           Field(min_length=1)] = [[0.0, 0.0]]   # x, y (m) of the elevation probes
    preview: PreviewTime = 0.0                           # s of future wave elevation at the probes
    preview_step: Duration | None = None                 # s between preview samples; default period
    latency: LatencySteps = 1              # steps from measurement to command
    timeout: WallTimeout = 1.0                           # s per command, wall clock
    join_timeout: WallTimeout = 30.0                   # s the run waits at t = 0 for the controller
    fallback: Literal["hold", "passive"] = "hold"
    fallback_damping: NonNegativeCoefficient | None = None
    # bodies (with hydro_states) whose hydrodynamic state this controller may command (SPEC §5.7.4
    # ``hydro_state``; server/hydro_states.py); a state commanded from step k's measurements acts from
    # step k + latency + 1
    hydro_states: list[Name] = []
    max_force: PositiveCoefficient | None = None               # |force command| <= max_force
    damping_range: Annotated[list[Coefficient], Field(min_length=2, max_length=2)] = [0.0, 1.0e12]
    stiffness_range: Annotated[list[Coefficient], Field(min_length=2, max_length=2)] = [-1.0e12, 1.0e12]
    parameters: dict[str, Union[bool, ParameterInt, ParameterFloat, str, list[ParameterFloat], list[str]]] = {}   # for on_start

    @model_validator(mode="after")
    def _ranges(self) -> "Controller":
        for key in ("damping_range", "stiffness_range"):
            lo, hi = getattr(self, key)
            if lo > hi:
                raise ValueError(f"{key}: [min, max] with min <= max, got {[lo, hi]}")
        if self.damping_range[0] < 0:
            raise ValueError("damping_range: damping must be >= 0")
        if len(set(self.ptos)) != len(self.ptos):
            raise ValueError(f"ptos: repeated PTO in {self.ptos}")
        if self.fallback_damping is not None and self.fallback != "passive":
            raise ValueError('fallback_damping: only with fallback = "passive"')
        return self

    def steps_per_period(self, dt: float) -> int:
        return max(1, int(round((self.period or dt) / dt)))


class Scene(_Section):
    _notes: list[str] = PrivateAttr(default_factory=list)
    simulation: Simulation
    water: Water = Water()
    waves: Waves = StillWater(type="still")
    current: Current | None = None
    hydro: Hydro = Hydro()
    steady: Steady = Steady()
    optimize: Optimize = Optimize()
    coupling: Coupling = Coupling()
    bodies: Annotated[list[Body], Field(min_length=1)]
    point_masses: list[PointMass] = []
    joints: list[Joint] = []
    constraints: list[Constraint] = []
    ptos: list[PTO] = []
    moorings: list[Mooring] = []
    morison: list[MorisonElement] = []
    client: Client = ExudynClient(type="exudyn")
    controllers: list[Controller] = []
    hydro_switches: list[HydroSwitch] = []

    @model_validator(mode="after")
    def _cross_checks(self) -> "Scene":
        names = [b.name for b in self.bodies]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ValueError(f"bodies[{i}].name: duplicate body name {n!r}")
        points = [p.name for p in self.point_masses]
        for i, n in enumerate(points):
            if n in names or n in points[:i] or n == "ground":
                raise ValueError(f"point_masses[{i}].name: name {n!r} is already used")
        if "ground" in names:
            raise ValueError(f"bodies[{names.index('ground')}].name: 'ground' is reserved")
        for i, m in enumerate(self.morison):
            if m.body not in names:
                raise ValueError(f"morison[{i}].body: no body named {m.body!r} (known: {names})")
            if min(m.point_a[2], m.point_b[2]) >= 0.0:
                raise ValueError(f"morison[{i}]: the member lies above the still water line (z >= 0 at both ends)")
        stated: dict[str, str] = {}
        qtfs: dict[str, NemohQTF] = {}
        wamits: dict[str, WamitRun] = {}
        for i, b in enumerate(self.bodies):
            if b.hdb is not None and b.hdb_convention is not None:
                if stated.setdefault(b.hdb, b.hdb_convention) != b.hdb_convention:
                    raise ValueError(f"bodies[{i}].hdb_convention: {b.hdb_convention} but another body states "
                                     f"{stated[b.hdb]} for the same HDB {b.hdb!r}")
            if b.wamit is not None and wamits.setdefault(b.hdb, b.wamit) != b.wamit:
                raise ValueError(f"bodies[{i}].wamit: differs from another body's wamit for the same HDB {b.hdb!r} "
                                 "(the facts are the run's: state them once, or the same)")
            if b.qtf is not None and qtfs.setdefault(b.hdb, b.qtf) != b.qtf:
                raise ValueError(f"bodies[{i}].qtf: differs from another body's qtf for the same HDB {b.hdb!r} "
                                 "(the QTF belongs to the HDB: state it once, or the same)")
        rigid = set(names) | {"ground"}
        anything = rigid | set(points)

        def known(key: str, name: str, allowed: set[str], what: str) -> None:
            if name not in allowed:
                raise ValueError(f"{key}: no {what} named {name!r} (known: {sorted(allowed)})")

        for i, j in enumerate(self.joints):   # point masses: spherical joints only (rope connection points)
            allowed = anything if j.type == "spherical" else rigid
            known(f"joints[{i}].body1", j.body1, allowed, "body")
            known(f"joints[{i}].body2", j.body2, allowed, "body")
        for i, c in enumerate(self.constraints):
            known(f"constraints[{i}].body", c.body, set(names), "body")
        for i, p in enumerate(self.ptos):
            known(f"ptos[{i}].body1", p.body1, rigid, "body")
            known(f"ptos[{i}].body2", p.body2, rigid, "body")
            if p.body1 == p.body2:
                raise ValueError(f"ptos[{i}].body2: a PTO needs two different bodies")
        pto_names = [p.name for p in self.ptos]
        for i, n in enumerate(pto_names):
            if n in pto_names[:i]:
                raise ValueError(f"ptos[{i}].name: duplicate PTO name {n!r}")
        for i, m in enumerate(self.moorings):
            if isinstance(m, LinearMooring):
                known(f"moorings[{i}].body", m.body, set(names), "body")
            elif isinstance(m, MoorDynMooring):
                for key in ("bodies", "points"):
                    for j, b in enumerate(getattr(m, key)):
                        known(f"moorings[{i}].{key}[{j}]", b, set(names), "body")
                if m.name in [getattr(o, "name", None) for o in self.moorings[:i]]:
                    raise ValueError(f"moorings[{i}].name: duplicate mooring name {m.name!r}")
            else:
                known(f"moorings[{i}].attach_to", m.attach_to, set(names) | set(points), "body or point mass")
                if m.attach_to in names and m.point is None:
                    raise ValueError(f"moorings[{i}].point: required when a rope is attached to a body")
        if self.hydro.sum_frequency and all(self.second_order_of(b) == "none" for b in self.bodies):
            raise ValueError("hydro.sum_frequency: adds to a second-order force: set hydro.second_order (or a "
                             "wet body's second_order) other than \"none\"")
        if isinstance(self.client, FMUClient):
            self.client.check(self)
        self._check_current()
        self._check_hydro_switches(names)
        self._check_controllers(names)
        self._check_optimize_limits(names)
        self._check_coupling()
        return self

    def _check_hydro_switches(self, names: list[str]) -> None:
        """Each rule names a body with hydro_states, one of its states and a DOF it moves in; one body per
        scene switches (each state is a whole model: server/hydro_states.py)."""
        switching = [i for i, b in enumerate(self.bodies) if b.hydro_states]
        if len(switching) > 1:
            raise ValueError(f"bodies[{switching[1]}].hydro_states: one body per scene may switch hydrodynamic "
                             f"state (bodies[{switching[0]}] does already): the server builds a model per state, "
                             "not per combination of several bodies' states")
        if switching and self.coupling.scheme not in ("auto", "mass-matrix"):
            raise ValueError(f"coupling.scheme: {self.coupling.scheme!r} with bodies[{switching[0]}].hydro_states: a "
                             "switch changes A-infinity in the client's mass matrix, which only \"mass-matrix\" "
                             "(the default) takes at a step (the explicit and implicit schemes feed it back)")
        for i, rule in enumerate(self.hydro_switches):
            if rule.body not in names:
                raise ValueError(f"hydro_switches[{i}].body: no body named {rule.body!r} (known: {names})")
            b = self.bodies[names.index(rule.body)]
            if not b.hydro_states:
                raise ValueError(f"hydro_switches[{i}].body: body {rule.body!r} has no hydro_states to switch between")
            if rule.state not in b.state_names():
                raise ValueError(f"hydro_switches[{i}].state: body {rule.body!r} has no state {rule.state!r} "
                                 f"(its states: {b.state_names()})")
            if rule.dof is not None and rule.dof not in b.dofs:
                raise ValueError(f"hydro_switches[{i}].dof: {rule.dof!r} is locked on body {rule.body!r} (dofs "
                                 f"{b.dofs}): its displacement stays 0")
            if rule.time is not None and rule.time >= self.simulation.duration:
                self._notes.append(f"hydro_switches[{i}].time: {rule.time:g} s is not before the run's end "
                                   f"(simulation.duration = {self.simulation.duration:g} s): it never switches")

    def _check_current(self) -> None:
        c = self.current
        if c is None:
            return
        if c.depth is not None and c.depth > self.water.depth_m:
            raise ValueError(f"current.depth: {c.depth:g} m is below the seabed (water.depth = {self.water.depth_m:g} m)")
        if not self.current_users():
            self._notes.append("current: nothing in this scene feels the current (it acts on bodies[i].drag with "
                               "relative = true, morison members and MoorDyn lines): it changes no result")

    def current_users(self) -> list[str]:
        """The keys of what feels ``[current]``: relative drag, Morison members, MoorDyn moorings, and
        the waves with ``current.doppler``."""
        users = ["current.doppler"] if self.current is not None and self.current.doppler and \
            getattr(self.waves, "type", "still") != "still" else []
        users += [f"bodies[{i}].drag" for i, b in enumerate(self.bodies) if b.drag is not None and b.drag.relative]
        users += [f"morison[{i}]" for i in range(len(self.morison))]
        return users + [f"moorings[{i}]" for i, m in enumerate(self.moorings) if isinstance(m, MoorDynMooring)]

    def _check_coupling(self) -> None:
        fmu = isinstance(self.client, FMUClient)
        if fmu and self.client.coupling is not None:
            self._adopt_fmu_coupling(self.client.coupling)
        c = self.coupling
        if c == Coupling():
            return
        if fmu and c.exchange_every > 1:
            raise ValueError("coupling.exchange_every: an FMU client exchanges every simulation.dt (its own "
                             "steps within are client.communication_step)")
        if c.exchange_every > 1:
            h = c.exchange_every * self.simulation.dt
            n = self.simulation.duration / h
            if abs(n - round(n)) > 1e-6 * max(1.0, n):
                raise ValueError(f"coupling.exchange_every: the exchange interval exchange_every * dt = {h:g} s "
                                 f"must divide simulation.duration = {self.simulation.duration:g} s")
            if self.controllers:
                raise ValueError("coupling.exchange_every: controllers need an exchange every step (1)")
        if self.controllers and c.scheme not in ("auto", "mass-matrix"):
            raise ValueError(f"coupling.scheme: controllers run with the \"mass-matrix\" scheme only "
                             f"(got \"{c.scheme}\")")

    def _adopt_fmu_coupling(self, old: "FMUCoupling") -> None:
        """The deprecated ``[client.coupling]`` read as ``[coupling]`` (which must then be absent)."""
        if self.coupling.model_fields_set:
            raise ValueError("client.coupling: deprecated, and [coupling] is given too: keep only [coupling]")
        scheme = MODE_SCHEME[old.mode]
        self.__dict__["coupling"] = Coupling(scheme=scheme, tolerance=old.tolerance,
                                             max_iterations=old.max_iterations, explicit_limit=old.explicit_limit)
        self._notes.append(
            f"client.coupling is deprecated: write [coupling] scheme = \"{scheme}\", tolerance = {old.tolerance:g}, "
            f"max_iterations = {old.max_iterations}, explicit_limit = {old.explicit_limit:g} (mode \"{old.mode}\" "
            f"is scheme \"{scheme}\")")

    @property
    def notes(self) -> list[str]:
        """What the scene says that works but should be written otherwise (deprecated keys)."""
        return list(self._notes)

    def _check_optimize_limits(self, names: list[str]) -> None:
        """``[[optimize.limits]]`` name PTOs (a rotary PTO's axis as name.axis) and bodies of the scene
        (``hydrolink run`` reads their series after the run: a wrong name must fail before it)."""
        labels = {p.name for p in self.ptos if isinstance(p, LinearPTO)}
        labels |= {f"{p.name}.{a}" for p in self.ptos if not isinstance(p, LinearPTO) for a in p.axes}
        for i, lim in enumerate(self.optimize.limits):
            if lim.pto is not None and lim.pto not in labels:
                raise ValueError(f"optimize.limits[{i}].pto: no PTO named {lim.pto!r} (known: {sorted(labels)}; "
                                 "a rotary PTO's axes are named pto.axis)")
            if lim.body is not None and lim.body not in names:
                raise ValueError(f"optimize.limits[{i}].body: no body named {lim.body!r} (known: {sorted(names)})")

    def _check_controllers(self, names: list[str]) -> None:
        linear = {p.name: p for p in self.ptos if isinstance(p, LinearPTO)}
        driven: dict[str, str] = {}
        dt = self.simulation.dt
        for i, c in enumerate(self.controllers):
            for b in c.hydro_states:
                if b not in names or not self.bodies[names.index(b)].hydro_states:
                    raise ValueError(f"controllers[{i}].hydro_states: {b!r} is not a body with hydro_states "
                                     f"(those: {[x.name for x in self.bodies if x.hydro_states]})")
            if c.name in [d.name for d in self.controllers[:i]]:
                raise ValueError(f"controllers[{i}].name: duplicate controller name {c.name!r}")
            for p in c.ptos:
                if p in linear and linear[p].direction is not None:
                    raise ValueError(f"controllers[{i}].ptos: PTO {p!r} is given by a direction; a controller "
                                     "drives PTOs given by point2")
                if p in {q.name for q in self.ptos} and p not in linear:
                    raise ValueError(f"controllers[{i}].ptos: {p!r} is not a linear PTO (controllers drive "
                                     "linear PTOs only)")
                if p not in linear:
                    raise ValueError(f"controllers[{i}].ptos: no PTO named {p!r} (known: {sorted(linear)})")
                if p in driven:
                    raise ValueError(f"controllers[{i}].ptos: PTO {p!r} is already driven by controller {driven[p]!r}")
                driven[p] = c.name
            for b in c.bodies or []:
                if b not in names:
                    raise ValueError(f"controllers[{i}].bodies: no body named {b!r} (known: {sorted(names)})")
            for key in ("period", "preview_step"):
                v = getattr(c, key)
                if v is not None and (round(v / dt) < 1 or abs(v / dt - round(v / dt)) > 1e-6 * max(1.0, v / dt)):
                    raise ValueError(f"controllers[{i}].{key}: {v} s must be a multiple of simulation.dt = {dt} s "
                                     "(one step or more)")


    @property
    def exchange_dt(self) -> float:
        """s, the server's step: coupling.exchange_every client steps of simulation.dt (setup.dt)."""
        return float(self.simulation.dt) * int(self.coupling.exchange_every)

    @property
    def n_exchanges(self) -> int:
        """Exchanges with the server to simulation.duration (the last step index is this, setup.last_seq)."""
        return self.simulation.n_steps // int(self.coupling.exchange_every)

    def spectrum_files(self) -> list[tuple[str, str]]:
        """(key, file) of each sea system whose table is in a file (``waves.systems[i].file``)."""
        systems = self.waves.systems if isinstance(self.waves, SeaState) else []
        return [(f"waves.systems[{i}].file", s.file) for i, s in enumerate(systems) if s.file is not None]

    def with_spectra(self, tables: dict[str, tuple[list[float], list[float] | None, list]]) -> "Scene":
        """The scene with each spectrum file's table (by its key, :meth:`spectrum_files`) in its
        system; ValueError "key: why" where a table is not a spectrum (negative, unordered...) or missing."""
        if not self.spectrum_files():
            return self
        systems = list(self.waves.systems)
        for i, system in enumerate(systems):
            key = f"waves.systems[{i}].file"
            if system.file is None:
                continue
            if key not in tables:
                raise ValueError(f"{key}: the table of {system.file!r} was not given (a client reads the file "
                                 "and sends it in hello.spectra)")
            try:
                systems[i] = system.with_table(*tables[key])
            except ValidationError as exc:
                why = "; ".join(f"{'.'.join(str(x) for x in e['loc'])}: {e['msg'].removeprefix('Value error, ')}"
                                for e in exc.errors())
                raise ValueError(f"{key}: {system.file}: {why}") from None
        return self.model_copy(update={"waves": self.waves.model_copy(update={"systems": systems})})

    def gauge_files(self) -> list[tuple[str, "Gauge"]]:
        """(key, gauge) of each gauge of ``[waves] type = "gauges"`` (key ``waves.gauges[i].file``)."""
        gauges = self.waves.gauges if isinstance(self.waves, GaugeWaves) else []
        return [(f"waves.gauges[{i}].file", g) for i, g in enumerate(gauges)]

    def with_gauges(self, records: dict[str, tuple]) -> "Scene":
        """The scene with each gauge's record (time, eta) by its key (:meth:`gauge_files`); ValueError
        "key: why" where one is missing or the run would reach past its end (the sea the records give
        repeats with their length: not a measured sea any more)."""
        if not self.gauge_files():
            return self
        gauges = list(self.waves.gauges)
        for i, gauge in enumerate(gauges):
            key = f"waves.gauges[{i}].file"
            if key not in records:
                raise ValueError(f"{key}: the record of {gauge.file!r} was not given (a client reads the file "
                                 "and sends it in hello.gauges)")
            time, eta = records[key]
            gauges[i] = gauge.with_record(time, eta)
            if len(time) >= 2:
                start = time[0] if self.waves.start is None else self.waves.start
                end = time[0] + len(time) * (time[-1] - time[0]) / (len(time) - 1)   # the window's end
                if not time[0] <= start or start + self.simulation.duration > end * (1 + 1e-12) + 1e-9:
                    raise ValueError(f"{'waves.start' if self.waves.start is not None else 'simulation.duration'}: "
                                     f"the run covers [{start:.6g}, {start + self.simulation.duration:.6g}] s of "
                                     f"the records and {gauge.file} covers [{time[0]:.6g}, {end:.6g}) s: the "
                                     "reconstructed sea repeats past the records' end (a shorter run or a later "
                                     "waves.start inside them)")
        return self.model_copy(update={"waves": self.waves.model_copy(update={"gauges": gauges})})

    def modal_files(self) -> list[tuple[str, int, "Body"]]:
        """(key, index, body) of each body whose modes' structure is a file (``bodies[i].modes.mmx``)."""
        return [(f"bodies[{i}].modes.mmx", i, b) for i, b in enumerate(self.bodies)
                if b.modes is not None and b.modes.mmx is not None]

    def with_modal_structure(self, blocks: dict[str, "ExternalMatrices"]) -> "Scene":
        """The scene with each structure file's body block (by its key, :meth:`modal_files`) in the
        body's modes; ValueError "key: why" where one is missing or is not the modes' structure
        (BodyModes.with_file)."""
        if not self.modal_files():
            return self
        bodies = list(self.bodies)
        for key, i, body in self.modal_files():
            if key not in blocks:
                raise ValueError(f"{key}: the matrices of {body.modes.mmx!r} were not given (a client reads the file "
                                 "and sends it in hello.modal_structure)")
            try:
                modes = body.modes.with_file(blocks[key])
            except ValueError as exc:
                raise ValueError(f"bodies[{i}].modes.{exc}") from None
            bodies[i] = body.model_copy(update={"modes": modes})
        return self.model_copy(update={"bodies": bodies})

    def hdb_keys(self) -> list[tuple[int, Body, str, str]]:
        """Every HDB the scene names, in scene order: (body index, body, the ``hdb`` string, its scene
        key) for each wet body's ``hdb`` and each of its ``hydro_states``' (repeats included)."""
        out = []
        for i, b in enumerate(self.bodies):
            if b.hdb is not None:
                out.append((i, b, b.hdb, f"bodies[{i}].hdb"))
            out.extend((i, b, s.hdb, f"bodies[{i}].hydro_states[{j}].hdb") for j, s in enumerate(b.hydro_states))
        return out

    def fixed_to_ground(self) -> dict[str, list[int]]:
        """{body: the indices of the ``fixed`` joints that join it to ground}, in joint order."""
        out: dict[str, list[int]] = {}
        for i, j in enumerate(self.joints):
            if j.type == "fixed" and "ground" in (j.body1, j.body2):
                out.setdefault(j.body2 if j.body1 == "ground" else j.body1, []).append(i)
        return out

    @property
    def wet_bodies(self) -> list[Body]:
        return [b for b in self.bodies if b.wet]

    @property
    def served_bodies(self) -> list[Body]:
        """The bodies the force server computes forces for, in scene order: the wet bodies and the
        bodies without an HDB that carry Morison elements (Morison-only: no radiation, excitation
        or hydrostatics; the client applies their weight and buoyancy as a dry body's)."""
        carried = {m.body for m in self.morison}
        return [b for b in self.bodies if b.wet or b.name in carried]

    def nonlinear_of(self, body: Body) -> str:
        """The body's nonlinear hydrostatics mode: its own ``nonlinear``, else ``[hydro] nonlinear``
        for a wet body; "none" for a dry one."""
        if not body.wet:
            return "none"
        return body.nonlinear if body.nonlinear is not None else self.hydro.nonlinear

    def nonlinear_key(self) -> str | None:
        """The key that makes some body's hydrostatics nonlinear (``bodies[i].nonlinear`` or
        ``hydro.nonlinear``), for a tool that refuses them; None when every body is linear."""
        for i, b in enumerate(self.bodies):
            if b.nonlinear not in (None, "none") and b.wet:
                return f"bodies[{i}].nonlinear"
        return "hydro.nonlinear" if self.nonlinear_bodies else None

    @property
    def nonlinear_bodies(self) -> list[Body]:
        """The wet bodies whose hydrostatics are nonlinear."""
        return [b for b in self.bodies if self.nonlinear_of(b) != "none"]

    def wamit_statement(self, hdb: str) -> dict:
        """What the scene states for the WAMIT run ``hdb`` (``load_hdb(..., wamit=)``): its bodies'
        ``wamit`` table (keys given) and ``excitation_needed`` (False in still water: a run without
        ``.3`` is read then)."""
        table = next((b.wamit for b in self.bodies if b.hdb == hdb and b.wamit is not None), None)
        stated = table.model_dump(exclude_none=True) if table is not None else {}
        stated["excitation_needed"] = getattr(self.waves, "type", "still") != "still"
        return stated

    def second_order_of(self, body: Body) -> str:
        """The body's second-order wave force: its own ``second_order``, else ``[hydro]
        second_order`` for a wet body; "none" for a dry one."""
        if not body.wet:
            return "none"
        return body.second_order if body.second_order is not None else self.hydro.second_order

    def second_order_key(self, i: int) -> str:
        """The key that sets body ``i``'s second-order force (its own, else ``hydro.second_order``)."""
        return f"bodies[{i}].second_order" if self.bodies[i].second_order is not None else "hydro.second_order"

    def features(self) -> dict[str, str]:
        """The optional features this scene uses (protocol/capabilities.py ``FEATURES``), each with
        the first key that turns it on, in ``FEATURES`` order: what a tool that cannot take one
        names when it refuses the scene."""
        found: dict[str, str] = {}
        for i, b in enumerate(self.bodies):
            for key in ("linear_damping", "quadratic_damping", "drag"):
                if getattr(b, key) is not None:
                    found.setdefault(key, f"bodies[{i}].{key}")
        if self.morison:
            found["morison"] = "morison[0]"
        key = self.nonlinear_key()
        if key is not None:
            found["nonlinear_hydrostatics"] = key
        for i, b in enumerate(self.bodies):
            if self.nonlinear_of(b) == "froude-krylov":
                found["nonlinear_froude_krylov"] = (f"bodies[{i}].nonlinear" if b.nonlinear is not None
                                                    else "hydro.nonlinear")
                break
        for i, b in enumerate(self.bodies):
            if self.second_order_of(b) != "none":
                found["second_order"] = self.second_order_key(i)
                break
        for i, b in enumerate(self.bodies):
            if b.passive_yaw:
                found["passive_yaw"] = f"bodies[{i}].passive_yaw"
                break
        for i, b in enumerate(self.bodies):
            if b.modes is not None:
                found["generalized_modes"] = f"bodies[{i}].modes"
            if b.hydro_states:
                found["hydro_states"] = f"bodies[{i}].hydro_states"
                break
        for i, b in enumerate(self.bodies):
            if b.sections is not None:
                found.setdefault("sectional_loads", f"bodies[{i}].sections")
            if b.pressure_output:
                found.setdefault("panel_pressures", f"bodies[{i}].pressure_output")
        return {f: found[f] for f in FEATURES if f in found}


_UNION_TAGS = ("regular", "irregular", "still", "elevation", "sea", "components", "gauges", "linear", "rotary", "rope", "moordyn", "exudyn", "fmu")


def parse_scene(text: str, source: str | Path = "<scene>", *, check_files: bool = False,
                have_hdbs: Collection[str] = ()) -> Scene:
    """Parse and validate scene TOML text; raise SceneError naming the key. ``check_files``: the
    input files the scene names (relative to ``source``, a scene file's path) must exist, and a
    missing one is listed with the schema's problems in the same error (:func:`missing_files`;
    ``have_hdbs``: the ``hdb`` strings whose HDBs the caller already holds, not looked for)."""
    more = (lambda raw: missing_files(raw, source, have_hdbs)) if check_files else None
    return validate_toml(text, source, Scene, SceneError, _UNION_TAGS, more)


def load_scene(path: str | Path, *, check_files: bool = True, have_hdbs: Collection[str] = ()) -> tuple[Scene, str]:
    """Read a scene file; returns the validated scene and its text. Every problem in one SceneError:
    the schema's and (``check_files``) each input file it names that does not exist."""
    path = Path(path)
    text = read_toml_file(path, SceneError, "the scene file")
    scene = parse_scene(text, path, check_files=check_files, have_hdbs=have_hdbs)
    for note in scene.notes:
        log.warning("%s: %s", path, note)
    return scene, text


def missing_files(raw: dict, scene_path: str | Path, have_hdbs: Collection[str] = ()) -> list[tuple[str, str]]:
    """(key, why) for each input file a parsed scene document names (relative to ``scene_path``)
    that does not exist: the bodies' HDBs (a WAMIT run by its stem or ``.1``), hull meshes and NEMOH
    QTF files, the modes' structure files and build specs, the elevation series of ``[waves] type = "elevation"`` and
    ``"gauges"``, MoorDyn input files and the
    FMU of ``[client] type = "fmu"``. Read off the document as written, so that it runs whether or
    not the schema holds (a value of the wrong type is the schema's problem, not looked for here)."""
    problems: list[tuple[str, str]] = []

    def check(key: str, value, what: str = "file", exists=Path.is_file) -> None:
        if isinstance(value, str) and value:
            path = resolve_path(scene_path, value)
            if not exists(path):
                problems.append((key, f"{what} not found: {path}"))

    def tables(key: str) -> list[tuple[int, dict]]:
        value = raw.get(key)
        return [(i, t) for i, t in enumerate(value) if isinstance(t, dict)] if isinstance(value, list) else []

    seen = set(have_hdbs)
    for i, body in tables("bodies"):
        hdb = body.get("hdb")
        if isinstance(hdb, str) and hdb not in seen:
            seen.add(hdb)
            check(f"bodies[{i}].hdb", hdb, exists=lambda p: p.exists() or p.with_suffix(".1").exists())
        states = body.get("hydro_states")
        for j, state in enumerate(states if isinstance(states, list) else ()):
            hdb = state.get("hdb") if isinstance(state, dict) else None
            if isinstance(hdb, str) and hdb not in seen:
                seen.add(hdb)
                check(f"bodies[{i}].hydro_states[{j}].hdb", hdb,
                      exists=lambda p: p.exists() or p.with_suffix(".1").exists())
        check(f"bodies[{i}].mesh", body.get("mesh"))
        modes = body.get("modes")
        for key, what in (("mmx", "structure file"), ("shapes", "HDB build spec")):
            check(f"bodies[{i}].modes.{key}", modes.get(key) if isinstance(modes, dict) else None, what)
        qtf = body.get("qtf")
        for name in ("difference", "sum"):
            check(f"bodies[{i}].qtf.{name}", qtf.get(name) if isinstance(qtf, dict) else None)
    waves = raw.get("waves")
    systems = waves.get("systems") if isinstance(waves, dict) else None
    for i, system in enumerate(systems if isinstance(systems, list) else ()):
        if isinstance(system, dict):
            check(f"waves.systems[{i}].file", system.get("file"), "spectrum file")
    gauges = waves.get("gauges") if isinstance(waves, dict) and waves.get("type") == "gauges" else None
    for i, gauge in enumerate(gauges if isinstance(gauges, list) else ()):
        if isinstance(gauge, dict):
            check(f"waves.gauges[{i}].file", gauge.get("file"), "gauge record")
    for section, kind, key, what in (("waves", "elevation", "file", "elevation file"), ("client", "fmu", "fmu", "FMU")):
        table = raw.get(section)
        if isinstance(table, dict) and table.get("type") == kind:
            check(f"{section}.{key}", table.get(key), what)
    for i, mooring in tables("moorings"):
        if mooring.get("type") == "moordyn":
            check(f"moorings[{i}].file", mooring.get("file"), "MoorDyn input file")
    return problems


def resolve_path(scene_path: str | Path, relative: str) -> Path:
    """Resolve a path written in a scene against the scene file's folder (made absolute, symlinks
    kept: a linked WAMIT ``.1`` finds its sibling files beside the link)."""
    import os
    p = Path(relative).expanduser()
    return p if p.is_absolute() else Path(os.path.abspath(Path(scene_path).parent / p))
