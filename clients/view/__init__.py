"""``hydrolink view``: a run's results file as a ParaView time series (transient VTKHDF files) and
a matplotlib animation: the bodies' meshes moved by the run, the free surface, moorings, markers."""
