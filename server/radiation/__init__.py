"""Radiation memory: the impulse response function and A-infinity (`irf.py`), direct convolution
(`convolution.py`), state-space fits and their cache, and the `[hydro] radiation` options that pick
one (`options.py`)."""
