"""The sea: wave components, spectra, ramp and excitation (`waves.py`), linear dispersion
(`dispersion.py`: the one `wave_number`), undisturbed kinematics at points (`kinematics.py`) and the
wave probes of controllers' measurements (`probes.py`)."""
