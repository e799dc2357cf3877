"""The network service on top of the physics: the ROUTER loop (`force_server.py`), sessions
(`session.py`), the controller hub (`controllers.py`),
set-up workers, capacity bounds and log limits. Nothing below `service/` imports it."""
