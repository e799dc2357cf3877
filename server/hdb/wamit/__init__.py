"""WAMIT output read once into the internal HDB: the run's facts from its files or the scene (`run.py`:
XBODY, ULEN, g, depth, VCG, IPEROUT), the first-order reader (`reader.py`: `.1`, `.3`/`.2`, `.hst`), the
second-order files (`second_order.py`: mean drift `.7`-`.9`, QTFs `.10d`-`.12s`) and the free-format tables
with their units (`table.py`)."""
