"""Passive damping: F = c v on every PTO the controller drives (force commands).

Parameters (scene ``[[controllers]] parameters``): ``damping`` (N s/m).
The PTO's own scene damping should then be 0 (the command is added to the connector's force).
"""

from hydrolink.clients.control import Controller


class PassiveDamping(Controller):
    def on_start(self, info):
        self.c = float(info["parameters"]["damping"])

    def on_step(self, t, m):
        return {p: self.c * v for p, v in zip(self.ptos, m["pto_velocity"].tolist())}
