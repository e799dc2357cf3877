"""The lockstep driver and what it talks through: the coupling schemes, the server connection, the results file, the controllers' multibody side."""
