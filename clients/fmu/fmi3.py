"""FMI 3.0 co-simulation slave behind the small interface the FMU master uses (fmpy low-level API).

FMI 3 quirks handled here: the instantiation token instead of a GUID, typed setters (Float64, Int32,
...), ``doStep`` reporting early return / termination, and ``get/setFMUState`` spelled with a
capital S. Inputs may be set only once per communication point, so the master rolls back with
``restore_state`` before setting them again (it does so whenever it iterates).
"""

from __future__ import annotations

from ctypes import byref
from typing import Any, Sequence

from fmpy.fmi3 import FMU3Slave, fmi3FMUState

VERSION = "3.0"

_INT_TYPES = ("Int8", "UInt8", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Enumeration")


class FMI3Slave:
    """One instance of an FMI 3.0 co-simulation FMU, instantiated (initialised by :meth:`initialize`)."""

    def __init__(self, model_description: Any, unzip_dir: str, instance_name: str = "hydrolink",
                 start_time: float = 0.0):
        md = model_description
        self.can_rollback = bool(md.coSimulation.canGetAndSetFMUstate)
        self._start = float(start_time)
        self._fmu = FMU3Slave(guid=md.instantiationToken, unzipDirectory=unzip_dir,
                              modelIdentifier=md.coSimulation.modelIdentifier, instanceName=instance_name)
        self._fmu.instantiate()

    def set_value(self, variable: Any, value: Any) -> None:
        """Set one variable of any type (parameters before :meth:`initialize`)."""
        t, vr = variable.type, [variable.valueReference]
        if t in ("Float64", "Float32"):
            getattr(self._fmu, f"set{t}")(vr, [float(value)])
        elif t in _INT_TYPES:
            setter = "setInt64" if t == "Enumeration" else f"set{t}"
            getattr(self._fmu, setter)(vr, [int(value)])
        elif t == "Boolean":
            self._fmu.setBoolean(vr, [bool(value)])
        elif t == "String":
            self._fmu.setString(vr, [str(value)])
        else:
            raise TypeError(f"cannot set the FMI 3 {t} variable {variable.name!r}")

    def initialize(self) -> None:
        self._fmu.enterInitializationMode(startTime=self._start)
        self._fmu.exitInitializationMode()

    def set_real(self, vrs: Sequence[int], values: Sequence[float]) -> None:
        self._fmu.setFloat64(vrs, values)

    def get_real(self, vrs: Sequence[int]) -> list[float]:
        return self._fmu.getFloat64(vrs)

    def do_step(self, t: float, h: float, *, may_roll_back: bool) -> None:
        """Advance t → t + h; an early return or a termination request is an error here."""
        _, terminate, early, last = self._fmu.doStep(t, h, noSetFMUStatePriorToCurrentPoint=not may_roll_back)
        if terminate or early:
            why = "asked to terminate" if terminate else f"returned early at t = {last:g} s"
            raise RuntimeError(f"the FMU {why} during the step {t:g} s -> {t + h:g} s")

    def save_state(self, into: Any = None) -> Any:
        """The FMU state (written into ``into`` when given: the FMU reuses that buffer)."""
        state = fmi3FMUState() if into is None else into
        self._fmu.fmi3GetFMUState(self._fmu.component, byref(state))
        return state

    def restore_state(self, state: Any) -> None:
        self._fmu.setFMUState(state)

    def free_state(self, state: Any) -> None:
        self._fmu.freeFMUState(state)

    def close(self) -> None:
        """Terminate and free the instance (and unload the library)."""
        try:
            self._fmu.terminate()
        finally:
            self._fmu.freeInstance()
