"""The linear core of a session's step (excitation, radiation, hydrostatics) as one compiled call."""
