"""The HDB contract: its layout (`layout.py`: names, dims, conventions), assembly and validation
(`schema.py`), second-order parts (`second_order.py`) and wire forms (`wire.py`)."""
