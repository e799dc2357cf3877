"""`hydrolink hdb build`: the build spec (`spec.py`), meshes (`mesh.py`, `overlap.py`), the
Capytaine solve and its cache (`builder.py`) and the far-field mean drift (`drift.py`)."""
