"""A joined controller's measurements and commands as fixed-layout binary frames on the direct
channel (SPEC §5.7.6, revision 1.20): no msgpack map on the controller's hot round trip.

The layout is fixed once, at the controller's ``welcome`` (``direct.frames``): the measurements'
names and shapes in order (float64, C order) and the command's slots (per PTO, the setpoints of
its command kind). Both frames start with the byte 0xC1, which msgpack never uses, so a receiver
tells a frame from a msgpack message by its first byte:

- a **command frame** (controller → server): a 32-byte header ``<BBHIIIqd`` (0xC1, ``C``, 0,
  ``request``, ``epoch``, 0, ``step``, ``wait``), then one float64 per command slot;
- a **measurements frame** (server → controller, the reply to a command frame): a 32-byte header
  ``<BBHIqqd`` (0xC1, ``M``, 0, ``request`` of the command it answers, ``step``, ``seq``,
  ``time``), then the measurements' float64 values, array after array in the layout's order.

Imports only numpy, the standard library and the codec, so a controller process starts fast.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from hydrolink.protocol.codec import Code, ProtocolError

MAGIC = 0xC1                  # "never used" in msgpack: no msgpack message starts with it
COMMAND, MEASUREMENTS = ord("C"), ord("M")
COMMAND_HEAD = struct.Struct("<BBHIIIqd")        # magic, kind, 0, request, epoch, 0, step, wait
MEASUREMENTS_HEAD = struct.Struct("<BBHIqqd")    # magic, kind, 0, request, step, seq, time
REQUESTS = 1 << 32            # a frame's request number is a uint32
_F8 = np.dtype("<f8")
_NUMBERS = (int, float, np.integer, np.floating)


def is_frame(frame: bytes | memoryview) -> bool:
    """Whether ``frame`` is a control frame (not a msgpack message)."""
    return len(frame) > 0 and frame[0] == MAGIC


@dataclass(frozen=True)
class Command:
    """A command frame's content: the values in the layout's slot order."""

    request: int
    epoch: int
    step: int
    wait: float
    values: tuple[float, ...]


@dataclass(frozen=True)
class ControlLayout:
    """The frames of one joined controller: ``measurements`` ((name, shape) in order) and
    ``commands`` ((pto, setpoint) slots in order, each PTO's setpoints together)."""

    measurements: tuple[tuple[str, tuple[int, ...]], ...]
    commands: tuple[tuple[str, str], ...]

    @cached_property
    def setpoints(self) -> int:
        """Setpoints per PTO (1 for force, 2 for impedance)."""
        ptos = {p for p, _ in self.commands}
        return len(self.commands) // max(len(ptos), 1)

    @cached_property
    def _arrays(self) -> tuple[tuple[str, tuple[int, ...], int, int], ...]:
        """Each measurement's (name, shape, values, byte offset in the measurements frame)."""
        out, at = [], MEASUREMENTS_HEAD.size
        for name, shape in self.measurements:
            out.append((name, shape, math.prod(shape), at))
            at += 8 * math.prod(shape)
        return tuple(out)

    def to_wire(self) -> dict:
        """``welcome.direct.frames``: {"measurements": [[name, shape], ...], "commands": [[pto, setpoint], ...]}."""
        return {"measurements": [[n, list(s)] for n, s in self.measurements],
                "commands": [[p, k] for p, k in self.commands]}

    @classmethod
    def from_wire(cls, value: Any) -> "ControlLayout":
        """The layout of ``welcome.direct.frames``; ValueError when it is not one."""
        try:
            meas = tuple((str(n), tuple(int(d) for d in s)) for n, s in value["measurements"])
            cmds = tuple((str(p), str(k)) for p, k in value["commands"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a control frame layout: {exc}") from None
        if any(d < 0 for _, s in meas for d in s):
            raise ValueError("a measurement's shape has a negative length")
        return cls(meas, cmds)

    # ------------------------------------------------------------ commands

    def command_frame(self, request: int, epoch: int, step: int, wait: float, commands: Any) -> bytes | None:
        """The command frame of ``commands`` (what ``Controller.on_step`` returns: {pto: number or
        {setpoint: number}}), or None when the layout cannot carry them (another PTO set, a missing
        or extra setpoint, a value not a number): those go as a msgpack ``command``, whose errors the
        server gives as before."""
        if type(commands) is not dict or len(commands) * self.setpoints != len(self.commands):
            return None
        values = []
        for pto, key in self.commands:
            v = commands.get(pto)
            if type(v) is dict:
                if len(v) != self.setpoints:
                    return None
                v = v.get(key)
            elif key != "force":
                return None
            if not isinstance(v, _NUMBERS) or isinstance(v, (bool, np.bool_)):
                return None
            values.append(float(v))
        return COMMAND_HEAD.pack(MAGIC, COMMAND, 0, request % REQUESTS, epoch % REQUESTS, 0, step, wait) \
            + struct.pack(f"<{len(values)}d", *values)

    def read_command(self, frame: bytes | memoryview) -> Command:
        """A command frame's content; ProtocolError 1 (malformed) for a frame not of this layout."""
        n = len(self.commands)
        if len(frame) != COMMAND_HEAD.size + 8 * n or frame[1] != COMMAND:
            raise ProtocolError(Code.MALFORMED, None, f"a control frame of {len(frame)} bytes, kind {frame[1]:#x}; "
                                f"this controller's command frame is kind {COMMAND:#x} of {COMMAND_HEAD.size + 8 * n} "
                                f"bytes ({n} setpoints, SPEC §5.7.6)")
        _, _, _, request, epoch, _, step, wait = COMMAND_HEAD.unpack_from(frame)
        return Command(request, epoch, step, wait, struct.unpack_from(f"<{n}d", frame, COMMAND_HEAD.size))

    # ------------------------------------------------------------ measurements

    def measurements_frame(self, request: int, sample: dict) -> bytes | None:
        """The measurements frame of a controller's ``measurements`` reply fields ``sample`` answering
        request ``request``, or None when the request's number is not a uint32 or ``sample`` does not
        hold the layout's arrays (measurements relayed without their wave probes): those go as msgpack."""
        if type(request) is not int or not 0 <= request < REQUESTS:
            return None
        parts = [MEASUREMENTS_HEAD.pack(MAGIC, MEASUREMENTS, 0, request, sample["step"], sample["seq"], sample["time"])]
        for name, shape in self.measurements:
            v = sample.get(name)
            if type(v) is not np.ndarray or v.shape != shape or v.dtype != _F8:
                return None
            parts.append(v.tobytes())
        return b"".join(parts)

    def read_measurements(self, frame: bytes) -> tuple[int, dict]:
        """(request, the measurements: ``step``, ``seq``, ``time`` and the arrays, read-only views of
        ``frame`` as a msgpack reply's are); ValueError for a frame not of this layout."""
        last = self._arrays[-1] if self._arrays else ("", (), 0, MEASUREMENTS_HEAD.size)
        size = last[3] + 8 * last[2]
        if len(frame) != size or frame[1] != MEASUREMENTS:
            raise ValueError(f"a control frame of {len(frame)} bytes, kind {frame[1]:#x}; the measurements frame "
                             f"is kind {MEASUREMENTS:#x} of {size} bytes")
        _, _, _, request, step, seq, time = MEASUREMENTS_HEAD.unpack_from(frame)
        out: dict[str, Any] = {"step": step, "seq": seq, "time": time}
        for name, shape, n, at in self._arrays:
            out[name] = np.frombuffer(frame, _F8, n, at).reshape(shape)
        return request, out
