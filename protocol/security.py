"""Transport security (SPEC §1.1): ZeroMQ CURVE authentication and encryption, via zmq.auth.

- ``hydrolink keys new DIR --name NAME`` writes ``NAME.key`` (public) and ``NAME.key_secret``
  (public + secret) with :func:`zmq.auth.create_certificates`.
- The server loads its ``*.key_secret`` file and the directory of allowed client public keys
  (every ``*.key`` in it, read at start); a ZAP handler (:class:`Authenticator`) admits exactly
  those keys and logs every refusal on the ``hydrolink.server.auth`` logger; a socket monitor logs
  the handshakes that fail before authentication (a plaintext client: mechanism mismatch; a client
  holding the wrong server key).
- A client needs the server's public key file and its own secret file.

The shared HMAC key of SPEC §3.3 (every message signed) lives in a key file too:
``hydrolink keys hmac FILE`` writes one (:func:`new_hmac_key`), ``--key-file`` (env
``HYDROLINK_KEY_FILE``) on ``serve``, ``run``, ``control`` reads it (:func:`read_hmac_key`).
"""

from __future__ import annotations

import logging
import os
import secrets
import threading
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator
from zmq.utils.monitor import recv_monitor_message

log = logging.getLogger("hydrolink.server.auth")


class CurveKeyError(ValueError):
    """A key file or directory that cannot be used; the message names it."""


def new_key_pair(directory: str | Path, name: str = "hydrolink") -> tuple[Path, Path]:
    """Write ``NAME.key`` and ``NAME.key_secret`` in ``directory`` (created); returns both paths."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    public, secret = zmq.auth.create_certificates(str(directory), name)
    Path(secret).chmod(0o600)
    return Path(public), Path(secret)


def load_keys(path: str | Path, *, secret: bool) -> tuple[bytes, bytes | None]:
    """(public, secret) z85 keys from a certificate file; ``secret=True`` requires the secret part."""
    path = Path(path)
    if not path.is_file():
        raise CurveKeyError(f"{path}: no such key file")
    try:
        public, private = zmq.auth.load_certificate(str(path))
    except (ValueError, OSError) as exc:
        raise CurveKeyError(f"{path}: not a CURVE certificate ({exc})") from None
    if secret and not private:
        raise CurveKeyError(f"{path}: holds no secret key (give the .key_secret file)")
    return public, private


@dataclass(frozen=True)
class ClientKeys:
    """What a client needs: the server's public key and its own key pair."""

    server_public: bytes
    public: bytes
    secret: bytes

    @classmethod
    def from_files(cls, server_key: str | Path, secret_file: str | Path) -> "ClientKeys":
        server_public, _ = load_keys(server_key, secret=False)
        public, secret = load_keys(secret_file, secret=True)
        return cls(server_public, public, secret)

    def apply(self, sock: zmq.Socket) -> None:
        """Make ``sock`` (before connect) a CURVE client of the server."""
        sock.curve_serverkey = self.server_public
        sock.curve_publickey = self.public
        sock.curve_secretkey = self.secret


def client_keys(server_key: str | Path | None, secret_file: str | Path | None) -> ClientKeys | None:
    """ClientKeys from the two options, None if neither is given; both or none."""
    if server_key is None and secret_file is None:
        return None
    if server_key is None or secret_file is None:
        raise CurveKeyError("CURVE needs both --curve-server-key (the server's public .key) and --curve-secret "
                        "(this client's .key_secret)")
    return ClientKeys.from_files(server_key, secret_file)


@dataclass(frozen=True)
class ServerKeys:
    """What a CURVE server needs (SPEC §1.1), read and checked before anything is bound: its key
    pair and the folder of the allowed clients' public keys (``allowed``: their ``*.key`` files'
    names, as read at start)."""

    public: bytes
    secret: bytes
    clients_dir: Path
    allowed: tuple[str, ...]


def server_keys(secret_file: str | Path | None, clients_dir: str | Path | None) -> ServerKeys | None:
    """ServerKeys from ``hydrolink serve``'s two options, None if neither is given; both or none.
    Cheap (no server import): the command checks them before it loads the server."""
    if secret_file is None and clients_dir is None:
        return None
    if secret_file is None or clients_dir is None:
        raise CurveKeyError("CURVE needs both the server's secret key file and the directory of "
                            "allowed client keys")
    public, secret = load_keys(secret_file, secret=True)
    clients_dir = Path(clients_dir)
    if not clients_dir.is_dir():
        raise CurveKeyError(f"{clients_dir}: no such directory of allowed client keys")
    return ServerKeys(public, secret, clients_dir, tuple(sorted(p.name for p in clients_dir.glob("*.key"))))


class EveryLine:
    """Log lines as they come: ``log(kind, level, msg, *args)`` on ``logger``. A server passes a
    bounded one instead (server/log_limit.LimitedLog: at most 20 a minute of each kind)."""

    def __init__(self, logger: logging.Logger):
        self.logger = logger

    def log(self, kind, level: int, msg: str, *args: object) -> None:
        self.logger.log(level, msg, *args)


class Authenticator(ThreadAuthenticator):
    """zmq.auth's ZAP handler, logging each CURVE refusal (and admission, at debug) with the key
    and peer address on ``hydrolink.server.auth``."""

    _address = ""
    lines = EveryLine(log)   # where refusals are logged (ServerSecurity's ``lines``)

    async def handle_zap_message(self, msg: list[bytes]) -> None:
        if len(msg) > 3:
            self._address = msg[3].decode("utf-8", "replace")
        await super().handle_zap_message(msg)

    async def _authenticate_curve(self, domain: str, client_key: bytes) -> tuple[bool, bytes]:
        allowed, reason = await super()._authenticate_curve(domain, client_key)
        key = zmq.utils.z85.encode(client_key).decode()
        if allowed:
            self.lines.log("admitted", logging.DEBUG, "CURVE client %s admitted (peer %s)", key, self._address)
        else:
            self.lines.log("refused", logging.WARNING, "refused CURVE client key %s from %s: %s (not in the allowed "
                            "client keys)", key, self._address or "?", reason.decode("utf-8", "replace"))
        return allowed, reason


_FAILURES = {  # a plaintext peer shows up as a protocol error or, when it hangs up first, NO_DETAIL (EPIPE)
    getattr(zmq, "EVENT_HANDSHAKE_FAILED_PROTOCOL", 0): "protocol error",
    getattr(zmq, "EVENT_HANDSHAKE_FAILED_NO_DETAIL", 0): "failed",
    getattr(zmq, "EVENT_HANDSHAKE_FAILED_AUTH", 0): "refused by the authenticator",
}


class ServerSecurity:
    """CURVE on a server socket: the authenticator (a thread on the socket's context) and a monitor
    thread logging failed handshakes. :meth:`close` stops both."""

    def __init__(self, ctx: zmq.Context, sock: zmq.Socket, keys: ServerKeys, lines=None):
        """``keys``: :func:`server_keys`' (checked); ``lines``: where refusals are logged (``log(kind,
        level, msg, *args)``), by default every line on ``hydrolink.server.auth``; a shared server
        bounds them (a client retrying in a loop)."""
        public, secret, clients_dir = keys.public, keys.secret, keys.clients_dir
        self.allowed = list(keys.allowed)
        if not self.allowed:
            log.warning("no client keys (*.key) in %s: every client will be refused", clients_dir)
        self.public = public
        self._lines = lines or EveryLine(log)
        self.auth = Authenticator(ctx, log=logging.getLogger("hydrolink.server.zap"))
        self.auth.lines = self._lines
        self.auth.start()
        try:   # (libzmq refuses a malformed key here: the authenticator's socket would hold the context open)
            self.auth.configure_curve(domain="*", location=str(clients_dir))
            sock.curve_server = True
            sock.curve_publickey = public
            sock.curve_secretkey = secret
        except BaseException:
            self.auth.stop()
            raise
        self._endpoint = f"inproc://hydrolink-monitor-{id(sock):x}"
        sock.monitor(self._endpoint, sum(e for e in _FAILURES if e))
        self._sock = sock
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, args=(ctx,), name="hydrolink-curve-monitor", daemon=True)
        self._thread.start()
        log.info("CURVE on: server key %s, %d allowed client key(s) from %s", public.decode(), len(self.allowed),
                 clients_dir)

    def _watch(self, ctx: zmq.Context) -> None:
        mon = ctx.socket(zmq.PAIR)
        mon.setsockopt(zmq.LINGER, 0)
        mon.connect(self._endpoint)
        try:
            while not self._stop.is_set():
                if not mon.poll(100):
                    continue
                event = recv_monitor_message(mon)
                if event["event"] == zmq.EVENT_MONITOR_STOPPED:
                    break
                what = _FAILURES.get(event["event"], f"event {event['event']}")
                if event["event"] != getattr(zmq, "EVENT_HANDSHAKE_FAILED_AUTH", -1):  # logged by the ZAP handler
                    self._lines.log("handshake", logging.WARNING, "refused a connection on %s: not a CURVE client "
                                    "of this server (a plaintext client, or one holding another server key): "
                                    "handshake %s (code %s)", event["endpoint"].decode("utf-8", "replace"), what,
                                    event["value"])
        except zmq.ZMQError:
            pass
        finally:
            mon.close(0)

    def close(self) -> None:
        self._stop.set()
        try:
            self._sock.disable_monitor()
        except zmq.ZMQError:
            pass
        self._thread.join(2.0)
        self.auth.stop()


# ---------------------------------------------------------------- HMAC key files (SPEC §3.3)

HMAC_KEY_BYTES = 32


def new_hmac_key(path: str | Path) -> Path:
    """Write a new shared HMAC key (32 random bytes, hex, one line) to ``path``, readable by its
    owner only; refuses to overwrite."""
    path = Path(path)
    if path.exists():
        raise CurveKeyError(f"{path} exists: choose another file (a key is never overwritten)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(secrets.token_hex(HMAC_KEY_BYTES) + "\n")
    return path


MAX_KEY_FILE_BYTES = 4096   # a key file is one line of hex: anything longer is not one (and is not read further)


def read_hmac_key(path: str | Path) -> bytes:
    """The shared key in a key file (hex, at least 32 bytes); CurveKeyError naming the file and
    why. At most MAX_KEY_FILE_BYTES + 1 bytes are read (a device such as /dev/zero is not read
    without end)."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_KEY_FILE_BYTES + 1)
    except OSError as exc:
        raise CurveKeyError(f"{path}: cannot read the key file: {exc.strerror}") from None
    how = "one line of hex digits; make one with `hydrolink keys hmac FILE`"
    if len(raw) > MAX_KEY_FILE_BYTES:
        raise CurveKeyError(f"{path}: not a key file: more than {MAX_KEY_FILE_BYTES} bytes ({how})")
    try:
        key = bytes.fromhex(raw.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        raise CurveKeyError(f"{path}: not a key file: {'binary data' if not raw.isascii() else 'not hex'} "
                            f"({how})") from None
    if len(key) < HMAC_KEY_BYTES:
        raise CurveKeyError(f"{path}: the key is {len(key)} bytes; at least {HMAC_KEY_BYTES}")
    return key
