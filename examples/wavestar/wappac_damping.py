"""A WAPPAC-style controller: the competition's signature, nothing of hydrolink imported.

WAPPAC (the WavePiston control competition, https://emg-mu.github.io/WAPPAC_docs/) asks its
entrants for ``my_controller(x, v, t, eta10)`` returning the PTO force F_pto (N), absorbed power
F_pto * v >= 0. This one is a passive linear damper, F_pto = c v. hydrolink runs it unchanged:

    hydrolink control examples/wavestar/wappac_damping.py --server tcp://127.0.0.1:PORT --token TOKEN

(x, v: the PTO's extension from rest and its rate; eta10: the elevation at the scene controller's
first wave probe; clients/control.py, WappacController.) The damping is near the passive optimum of the WaveStar
PTO at the sea state's peak period (examples/wavestar/README.md).
"""

DAMPING = 400.0   # N s/m


def my_controller(x, v, t, eta10):
    return DAMPING * v
