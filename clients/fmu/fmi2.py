"""FMI 2.0 co-simulation slave behind the small interface the FMU master uses (fmpy low-level API)."""

from __future__ import annotations

from ctypes import byref
from typing import Any, Sequence

from fmpy.fmi2 import FMU2Slave, fmi2False, fmi2FMUstate, fmi2True

VERSION = "2.0"


class FMI2Slave:
    """One instance of an FMI 2.0 co-simulation FMU, instantiated and set up at ``start_time``."""

    def __init__(self, model_description: Any, unzip_dir: str, instance_name: str = "hydrolink",
                 start_time: float = 0.0):
        md = model_description
        self.can_rollback = bool(md.coSimulation.canGetAndSetFMUstate)
        self._fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip_dir,
                              modelIdentifier=md.coSimulation.modelIdentifier, instanceName=instance_name)
        self._fmu.instantiate()
        self._fmu.setupExperiment(startTime=start_time)
        self._setters = {"Real": self._fmu.setReal, "Integer": self._fmu.setInteger,
                         "Enumeration": self._fmu.setInteger, "Boolean": self._fmu.setBoolean,
                         "String": self._fmu.setString}

    def set_value(self, variable: Any, value: Any) -> None:
        """Set one variable of any type (parameters before :meth:`initialize`)."""
        if variable.type == "String":
            value = str(value)
        elif variable.type == "Boolean":
            value = bool(value)
        elif variable.type in ("Integer", "Enumeration"):
            value = int(value)
        else:
            value = float(value)
        self._setters[variable.type]([variable.valueReference], [value])

    def initialize(self) -> None:
        self._fmu.enterInitializationMode()
        self._fmu.exitInitializationMode()

    def set_real(self, vrs: Sequence[int], values: Sequence[float]) -> None:
        self._fmu.setReal(vrs, values)

    def get_real(self, vrs: Sequence[int]) -> list[float]:
        return self._fmu.getReal(vrs)

    def do_step(self, t: float, h: float, *, may_roll_back: bool) -> None:
        """Advance t → t + h; ``may_roll_back`` tells the FMU a setFMUstate to before t may follow."""
        self._fmu.doStep(t, h, noSetFMUStatePriorToCurrentPoint=fmi2False if may_roll_back else fmi2True)

    def save_state(self, into: Any = None) -> Any:
        """The FMU state (written into ``into`` when given: the FMU reuses that buffer)."""
        state = fmi2FMUstate() if into is None else into
        self._fmu.fmi2GetFMUstate(self._fmu.component, byref(state))
        return state

    def restore_state(self, state: Any) -> None:
        self._fmu.setFMUstate(state)

    def free_state(self, state: Any) -> None:
        self._fmu.freeFMUstate(state)

    def close(self) -> None:
        """Terminate and free the instance (and unload the library)."""
        try:
            self._fmu.terminate()
        finally:
            self._fmu.freeInstance()
