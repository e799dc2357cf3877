"""docker/: no Docker engine runs here, so the entry points the image and the compose file use are
run directly — the Dockerfile's ENTRYPOINT with its ENV, the compose services' entry points with
their environments — on loopback (host ``server`` -> 127.0.0.1, the mounts -> local folders)."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import xarray as xr

from conftest import EXIT_S, REPLY_S, rm3_example_text, stopped

yaml = pytest.importorskip("yaml")

REPO = Path(__file__).resolve().parents[1]


def dockerfile() -> tuple[list[str], dict[str, str]]:
    """The Dockerfile's ENTRYPOINT (exec form) and ENV."""
    entry, env = None, {}
    for line in (REPO / "docker" / "Dockerfile").read_text().splitlines():
        if line.startswith("ENTRYPOINT "):
            entry = json.loads(line.split(" ", 1)[1])
        elif line.startswith("ENV "):
            key, value = line.split(" ", 1)[1].split("=", 1)
            env[key] = value
    assert entry, "no ENTRYPOINT in docker/Dockerfile"
    return entry, env


def executable(argv: list[str]) -> list[str]:
    """The console script as installed; the same command through this interpreter otherwise."""
    assert argv[0] == "hydrolink"
    found = shutil.which("hydrolink")
    return [found, *argv[1:]] if found else [sys.executable, "-m", "hydrolink.clients.cli", *argv[1:]]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_compose_stack_runs_on_loopback(reference_data, tmp_path):
    entry, image_env = dockerfile()
    compose = yaml.safe_load((REPO / "docker" / "compose.yaml").read_text())["services"]
    assert set(compose) == {"server", "client", "controller"}
    assert "entrypoint" not in compose["server"]    # the server runs the image's own entry point

    keys, scene_dir = tmp_path / "keys", tmp_path / "scene"
    for folder, name in ((keys, "server"), (keys / "clients", "client")):
        out = subprocess.run(executable(["hydrolink", "keys", "new", str(folder), "--name", name]),
                             capture_output=True, text=True, timeout=EXIT_S)
        assert out.returncode == 0, out.stderr
    scene_dir.mkdir()
    text = rm3_example_text("rm3.toml")
    for a, b in (('"../data/rm3_wamit/rm3.1"', f'"{(reference_data / "rm3_wamit" / "rm3.1").as_posix()}"'),
                 ("duration = 400.0", "duration = 1.6")):
        text = text.replace(a, b)
    (scene_dir / "rm3.toml").write_text(text + '\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\ntimeout = 20.0\n'
                                        "parameters = { damping = 1.0e6, stiffness = 0.0 }\n")
    shutil.copy(REPO / "examples" / "controllers" / "reactive.py", scene_dir / "reactive.py")

    port = free_port()
    mounts = {"/keys": str(keys), "/scene": str(scene_dir), "tcp://server:5555": f"tcp://127.0.0.1:{port}",
              "tcp://0.0.0.0:5555": f"tcp://127.0.0.1:{port}",
              "${HYDROLINK_CONTROL_TOKEN}": secrets.token_urlsafe(32)}   # compose's interpolation

    def local(value: str) -> str:
        for a, b in mounts.items():
            value = value.replace(a, b)
        return value

    def environment(service: str) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("HYDROLINK_CURVE", "HYDROLINK_CONTROL"))}
        env.update({k: local(str(v)) for k, v in {**image_env, **compose[service].get("environment", {})}.items()})
        return env

    procs = []
    try:
        log = tmp_path / "server.log"
        with open(log, "w") as err:
            server = subprocess.Popen(executable(entry), env=environment("server"), stdout=subprocess.DEVNULL, stderr=err)
        procs.append(server)
        deadline = time.monotonic() + 120.0   # its start-up imports take seconds on a loaded machine
        while "listening on" not in log.read_text() and server.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert f"listening on tcp://127.0.0.1:{port} (CURVE" in log.read_text(), log.read_text()
        command = [local(a) for a in compose["controller"]["entrypoint"]]
        command[command.index("--join-wait") + 1] = str(REPLY_S)   # compose's 60 s: the run's hello, loaded, can take more
        ctl = subprocess.Popen(executable(command),
                               env=environment("controller"), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(ctl)
        out = subprocess.run(executable([local(a) for a in compose["client"]["entrypoint"]]), env=environment("client"),
                             capture_output=True, text=True, timeout=EXIT_S)
        assert out.returncode == 0, out.stderr
        _, err = ctl.communicate(timeout=EXIT_S)
        assert ctl.returncode == 0, err
        # a plaintext client is refused by the deployed server
        from hydrolink.clients.lockstep.connection import ServerConnection
        with ServerConnection(f"tcp://127.0.0.1:{port}", timeout=1.0) as conn:
            with pytest.raises(TimeoutError):
                conn.ping()
    finally:
        for p in procs:
            stopped(p)
    ds = xr.load_dataset(scene_dir / "rm3.out.nc")
    assert ds.sizes["time"] == 21
    assert json.loads(ds.attrs["controller_events"])["ctl"]["ok"] == 20
