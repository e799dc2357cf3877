"""Analyses of a scene without a lockstep run: its periodic steady state in regular waves by collocation
(`steady.py`, `hydrolink steady`) and its linear state-space plant about equilibrium (`plant.py`,
`hydrolink linearize`, and the plant a controller asks the server for)."""
