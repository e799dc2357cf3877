"""FMI: the FMU master (fmi2/fmi3 quirks each in its own module, the coupling numerics) and the two exports (native C, Python)."""
