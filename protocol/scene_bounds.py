"""The bounds of every numeric scene value: one annotated type per kind of quantity.

Each type is a float (or int) with pydantic bounds (``Field(ge=, gt=, le=, lt=)``, finite) and the
reason for them; a value outside gets pydantic's message ("Input should be less than or equal to
...") and the reason in the error's context (``ctx["why"]``, which protocol/toml_model.py appends).
The ranges are generous for a wave energy converter but finite: no value a scene can hold
overflows a step count, a wave number or an allocation (huge ints and 1e300 included).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field, ValidationError, WrapValidator
from pydantic_core import PydanticCustomError

#: pydantic error types of a value outside its bounds (the others: wrong type, not parsable)
BOUND_ERRORS = frozenset({"greater_than", "greater_than_equal", "less_than", "less_than_equal", "finite_number"})

MAX_STEPS = 10**8   # simulation.duration / dt (and per-step arrays over a run) at most


def _reason(why: str, floor: float | None) -> WrapValidator:
    """Re-raise a bound error of the wrapped value with ``why`` in its context; then refuse a value
    below ``floor`` (a physical floor above a sign bound, so that -1 still reads "greater than 0")."""
    def wrap(value: Any, handler: Any) -> Any:
        try:
            value = handler(value)
        except ValidationError as exc:
            err = exc.errors()[0]
            if err["type"] not in BOUND_ERRORS:
                raise
            raise PydanticCustomError(err["type"], err["msg"], {**err.get("ctx", {}), "why": why}) from None
        if floor is not None and value < floor:
            raise PydanticCustomError("greater_than_equal", "Input should be greater than or equal to {ge}",
                                      {"ge": floor, "why": why})
        return value
    return WrapValidator(wrap)


def bounded(*, why: str, ge: float | None = None, gt: float | None = None, le: float | None = None,
            lt: float | None = None, floor: float | None = None, kind: type = float) -> Any:
    """A finite ``kind`` value within the bounds given (``floor``: a lower bound checked after
    them), refused with ``why`` outside them."""
    finite = {"allow_inf_nan": False} if kind is float else {}
    return Annotated[kind, Field(ge=ge, gt=gt, le=le, lt=lt, **finite), _reason(why, floor)]


def count(low: int, high: int, why: str) -> Any:
    """An int in [low, high]."""
    return bounded(ge=low, le=high, why=why, kind=int)


# -- time
TimeStep = bounded(gt=0.0, floor=1e-6, le=3600.0, why="a time step from 1 µs to 1 h")
Duration = bounded(gt=0.0, le=1e7, why="at most 1e7 s (116 days) of simulated time")
Interval = bounded(gt=0.0, le=86400.0, why="seconds, at most a day")
RampTime = bounded(ge=0.0, le=1e7, why="at most the longest run, 1e7 s")
IRFDuration = bounded(ge=0.0, le=3600.0, why="a radiation memory of at most an hour")
ExcitationIRFDuration = bounded(gt=0.0, le=3600.0, why="an excitation IRF of at most an hour each side")
FileTime = bounded(ge=-1e10, le=1e10, why="a time in the elevation file within 1e10 s (epoch seconds fit)")
PreviewTime = bounded(ge=0.0, le=3600.0, why="at most an hour of wave preview")
WallTimeout = bounded(gt=0.0, le=86400.0, why="seconds of wall time, at most a day")

# -- water and waves (the ranges also bound an HDB's rho, g and water_depth: server/hdb/schema.py)
DENSITY_RANGE = (100.0, 2e4)     # kg/m^3
GRAVITY_RANGE = (0.1, 100.0)     # m/s^2
DEPTH_RANGE = (0.01, 1e5)        # m (or inf)
Density = bounded(ge=DENSITY_RANGE[0], le=DENSITY_RANGE[1], why="a liquid's density in kg/m^3 (sea water 1025)")
Gravity = bounded(ge=GRAVITY_RANGE[0], le=GRAVITY_RANGE[1], why="m/s^2 (Earth 9.81)")
Depth = bounded(ge=DEPTH_RANGE[0], le=DEPTH_RANGE[1], why="metres of water (or \"inf\")")
WaveHeight = bounded(ge=0.0, le=100.0, why="metres (the largest ocean waves are ~30 m)")
SignificantHeight = bounded(gt=0.0, floor=1e-4, le=100.0, why="metres (the largest ocean waves are ~30 m)")
WavePeriod = bounded(ge=0.1, le=1000.0, why="seconds, from ripples to swell")
PeakEnhancement = bounded(ge=1.0, le=20.0, why="JONSWAP gamma (North Sea 3.3)")
AngleDeg = bounded(ge=-720.0, le=720.0, why="degrees, within two turns")
Frequency = bounded(gt=0.0, le=1000.0, why="rad/s")
FrequencyStep = bounded(ge=1e-4, le=10.0, why="rad/s: a resampling step from 1e-4 to 10 rad/s")
Seed = bounded(ge=0, le=2**63 - 1, why="a 64-bit random seed", kind=int)
SpreadingExponent = bounded(gt=0.0, le=1000.0, why="cos-2s spreading exponent s")
CurrentSpeed = bounded(ge=0.0, le=10.0, why="m/s (the fastest tidal streams are ~5 m/s)")
ProfileDepth = bounded(gt=0.0, le=DEPTH_RANGE[1], why="metres below the still water line")

# -- bodies and mechanism (SI; coefficients up to 1e15 cover the largest structures)
Mass = bounded(gt=0.0, floor=1e-3, le=1e10, why="kg, from a gram to 10 million tonnes")
MAX_COORDINATE = 1e5   # m (or rad): also the bound of a step's position (server/service/session.py)
MAX_SPEED = 1e4        # m/s (or rad/s): also the bound of a step's velocity
Coordinate = bounded(ge=-MAX_COORDINATE, le=MAX_COORDINATE, why="metres, within 100 km of the origin")
Displacement = bounded(ge=-MAX_COORDINATE, le=MAX_COORDINATE, why="metres or radians, within 1e5")
Speed = bounded(ge=-MAX_SPEED, le=MAX_SPEED, why="m/s or rad/s, within 1e4")
Length = bounded(gt=0.0, le=1e5, why="metres, at most 100 km")
NonNegativeLength = bounded(ge=0.0, le=1e5, why="metres, at most 100 km")
Diameter = bounded(gt=0.0, le=1000.0, why="metres, at most 1 km")
NonNegativeDiameter = bounded(ge=0.0, le=1000.0, why="metres, at most 1 km")
Area = bounded(ge=0.0, le=1e8, why="m^2, at most 100 km^2")
Volume = bounded(ge=0.0, le=1e10, why="m^3, at most 1e10")
Coefficient = bounded(ge=-1e15, le=1e15, why="an SI coefficient within 1e15")
NonNegativeCoefficient = bounded(ge=0.0, le=1e15, why="an SI coefficient from 0 to 1e15")
PositiveCoefficient = bounded(gt=0.0, le=1e15, why="an SI coefficient up to 1e15")
LineDensity = bounded(gt=0.0, le=1e6, why="kg/m, at most 1000 t/m")
FlowCoefficient = bounded(ge=0.0, le=100.0, why="a dimensionless drag or added-mass coefficient up to 100")
RegularisationSpeed = bounded(ge=1e-9, le=1e3, why="m/s or rad/s, from 1e-9 to 1e3")
Fraction = bounded(ge=0.0, lt=1.0, why="a fraction in [0, 1)")
EnergyFraction = bounded(gt=0.0, le=1.0, why="a fraction of the wave variance in (0, 1]")
SpectralRadius = bounded(ge=0.0, le=1.0, why="the generalized-alpha spectral radius (1: no numerical damping)")
Efficiency = bounded(gt=0.0, le=1.0, why="a PTO efficiency in (0, 1]")
AddedMassRatio = bounded(gt=0.0, le=1.0, why="the largest added-mass ratio A_inf/m explicit coupling runs")
ExplicitSpectralRadius = bounded(gt=0.0, le=0.9, why="the largest spectral radius of M^-1 A_inf explicit coupling runs")
Tolerance = bounded(gt=0.0, lt=1.0, why="a relative tolerance in (0, 1)")

# -- counts
ComponentCount = count(1, 100_000, "spectral components")
DirectionCount = count(1, 360, "spreading directions")
StateSpaceOrder = count(2, 60, "a state-space order per DOF pair")
ExchangeSteps = count(1, 100_000, "client steps per exchange")
IterationCount = count(1, 1000, "iterations")
HarmonicCount = count(1, 200, "harmonics")
CableElements = count(1, 500, "cable elements")
SegmentCount = count(1, 1000, "segments per member")
LatencySteps = count(1, 1000, "steps")

# -- free parameters handed to an FMU or a controller: finite floats, 64-bit ints
ParameterFloat = bounded(ge=-1e300, le=1e300, why="a finite float")
ParameterInt = bounded(ge=-2**63, le=2**63 - 1, why="a 64-bit int", kind=int)
