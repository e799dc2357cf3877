"""A heaving body with a linear PTO damper as a pythonfmu3 (FMI 3.0) co-simulation FMU.

    m z'' = F - c_pto z' - k_hs z        F: the input force, constant over a communication step

No added-mass parameter: a master must handle A∞ itself (iterating with rollback). Every piece of
state is a registered variable, so pythonfmu3's get/set FMU state restores it completely. The body
starts at rest at z = 0 (outputs with initial="exact"). The FMI 3.0 twin of pyheave.py.
"""

from pythonfmu3 import Fmi3Causality, Fmi3Initial, Fmi3Slave, Fmi3Variability, Float64, Int32


class PyHeave3(Fmi3Slave):
    author = "hydrolink tests"
    description = "Heaving body with a PTO damper, no added-mass parameter"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.m, self.k_hs, self.c_pto = 261.8e3, 0.0, 0.0
        self.substeps = 10
        self.time, self.F = 0.0, 0.0
        self.z, self.v, self.P_pto, self.E_pto = 0.0, 0.0, 0.0, 0.0
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        for name in ("m", "k_hs", "c_pto"):
            self.register_variable(Float64(name, causality=Fmi3Causality.parameter,
                                           variability=Fmi3Variability.fixed))
        self.register_variable(Int32("substeps", causality=Fmi3Causality.parameter,
                                     variability=Fmi3Variability.fixed))
        self.register_variable(Float64("F", causality=Fmi3Causality.input))
        for name in ("z", "v", "P_pto", "E_pto"):
            self.register_variable(Float64(name, causality=Fmi3Causality.output, initial=Fmi3Initial.exact))

    def _rates(self, z: float, v: float) -> tuple[float, float, float]:
        return v, (self.F - self.c_pto * v - self.k_hs * z) / self.m, self.c_pto * v * v

    def do_step(self, current_time: float, step_size: float) -> bool:
        h = step_size / self.substeps
        z, v, e = self.z, self.v, self.E_pto
        for _ in range(self.substeps):
            k1 = self._rates(z, v)
            k2 = self._rates(z + 0.5 * h * k1[0], v + 0.5 * h * k1[1])
            k3 = self._rates(z + 0.5 * h * k2[0], v + 0.5 * h * k2[1])
            k4 = self._rates(z + h * k3[0], v + h * k3[1])
            z += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            v += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            e += h / 6 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        self.z, self.v, self.E_pto = z, v, e
        self.time = current_time + step_size
        self.P_pto = self.c_pto * v * v
        return True
