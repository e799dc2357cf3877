"""Loads on parts of a body for structural design: the internal loads along its axis (``sections.py``)
from the HDB build's panel pressures (server/hdb/build/panels.py) and a run's recorded motion."""
