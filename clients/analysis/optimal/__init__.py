"""``hydrolink optimize``: the PTO forces that maximise the absorbed power under limits (a QP on the
collocation model of ``hydrolink steady``), and the WECCCOMP metrics of a run with limits."""
