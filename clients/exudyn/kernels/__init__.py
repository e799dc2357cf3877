"""The Exudyn client's compiled arithmetic (numba): the embedded run's exchange (:mod:`.exchange`),
the joints' results rows (:mod:`.joints`), and the joints' reaction moment and friction share (:mod:`.joint_moments`:
plain Python the numpy path calls and :mod:`.joints` compiles). Importing this package imports no
numba; :mod:`.exchange` and :mod:`.joints` do, on first use."""
