"""The ``hydrolink`` command: build and inspect HDBs, serve forces, run scenes."""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from hydrolink.protocol.pacing import FACTOR_RANGE
from hydrolink.server.service.capacity import ISOLATE_STEP_S, MAX_SESSIONS, MAX_SETUPS, MAX_WORKERS, default_memory_mib


class _UserError(click.ClickException):
    """An error in the user's input, shown as one clear line (no traceback)."""


def _user_errors():
    """Exception types that are the user's input at fault and deserve a one-line message."""
    from hydrolink.protocol.scene import SceneError
    from hydrolink.protocol.hdb.layout import HDBError
    from hydrolink.clients.lockstep.connection import RemoteError
    errors: list[type[BaseException]] = [SceneError, HDBError, FileNotFoundError, RemoteError]
    from hydrolink.clients.exudyn.client import RunInterrupted
    from hydrolink.server.model import ModelError
    errors += [ModelError, RunInterrupted]
    return tuple(errors)


def _guard(func, *args, **kwargs):
    try:
        return func(*args, **kwargs)
    except _user_errors() as exc:
        raise _UserError(str(exc)) from None


def run_headline(output: str | Path) -> str | None:
    """The headline figures of a results file over the second half of its time (past the ramp and
    the start-up transient of most runs): per body, its translation and its rotation that vary most
    (standard deviation and largest magnitude of position - equilibrium), and the mean of
    ``total_pto_power`` where the scene has PTOs. None for a file of fewer than two rows."""
    import numpy as np
    import xarray as xr

    with xr.open_dataset(output, engine="netcdf4") as ds:
        t = ds["time"].values
        if t.size < 2:
            return None
        keep = t >= 0.5 * t[-1] - 0.25 * np.diff(t).min()   # (a row at half time, give or take rounding)
        motion = ds["position"].values[keep] - ds["equilibrium_position"].values[None]
        dofs = [str(d) for d in ds["dof"].values]
        parts = []
        for b, body in enumerate(ds["body"].values):
            said = []
            for span, unit, scale in ((slice(0, 3), "m", 1.0), (slice(3, 6), "deg", 180.0 / np.pi)):
                x = motion[:, b, span] * scale
                std = x.std(axis=0)
                if std.max() > 0.0:
                    d = int(np.argmax(std))
                    said.append(f"{dofs[span][d]} std {std[d]:.3g} {unit} (max |x| {np.abs(x[:, d]).max():.3g} {unit})")
            parts.append(f"{body} " + (", ".join(said) if said else "at rest"))
        if "total_pto_power" in ds:
            power = float(ds["total_pto_power"].values[keep].mean())
            parts.append(f"mean total PTO power {power / 1e3:.4g} kW" if abs(power) >= 1e3
                         else f"mean total PTO power {power:.4g} W")
    return f"t {t[keep][0]:g}-{t[-1]:g} s: " + "; ".join(parts)


def _pin_to_cpu(cpu: int | None) -> None:
    """Run this process (and the threads it starts later) on one CPU, e.g. the same CPU for
    ``serve`` and ``run``: lockstep has nothing to run in parallel, and waking another CPU for
    each message costs more than the message."""
    if cpu is None:
        return
    import os
    try:
        os.sched_setaffinity(0, {cpu})
    except (AttributeError, OSError, ValueError) as exc:
        raise _UserError(f"--cpu {cpu}: cannot pin to that CPU ({exc})") from None


def _check_rt_priority(priority: int | None) -> None:
    """One line now, before any set-up, when ``--rt-priority`` cannot be had (SCHED_FIFO taken and
    given back: clients/lockstep/rt_priority.py); the loop takes it later (docs/realtime.md)."""
    if priority is None:
        return
    from hydrolink.clients.lockstep.rt_priority import PriorityError, check_rt_priority
    try:
        check_rt_priority(priority)
    except PriorityError as exc:
        raise _UserError(str(exc)) from None


#: the longest duration an option may give, s (11.6 days)
MAX_SECONDS = 1.0e6


class Seconds(click.FloatRange):
    """A duration option: a finite number of the option's unit (``unit`` seconds: 1e-3 for
    milliseconds) from ``minimum`` (excluded when ``open_minimum``) to :data:`MAX_SECONDS`. NaN, inf and
    a larger value are refused naming the option, before they reach a socket's timeout (ZeroMQ's
    are milliseconds in a C int: 24.8 days) or a clock's arithmetic."""

    name = "seconds"

    def __init__(self, *, minimum: float = 0.0, open_minimum: bool = True, unit: float = 1.0):
        super().__init__(min=minimum, max=MAX_SECONDS / unit, min_open=open_minimum)

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if number != number:   # NaN passes FloatRange's comparisons
            self.fail(f"{value!r} is not a number of seconds", param, ctx)
        return number


RT_PRIORITY_HELP = ("Run the loop (not the set-up) under SCHED_FIFO at this real-time priority (1-98, Linux; "
                    "needs CAP_SYS_NICE or `ulimit -r`): woken ahead of the host's other work (docs/realtime.md).")


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="hydrolink")
@click.option("-v", "--verbose", count=True, help="More log output (-v info, -vv debug).")
def cli(verbose: int) -> None:
    """hydrolink: a hydrodynamic force server for wave energy converters, co-simulated with a
    multibody client (Exudyn) over ZeroMQ."""
    level = logging.WARNING - 10 * min(verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if verbose < 2:   # -vv keeps Python's own format (file and line of the warning)
        import warnings
        warnings.showwarning = _show_warning


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as the user reads it: one plain line on stderr, no source file or line."""
    text = " ".join(str(message).split())
    print(f"warning: {text}", file=file or sys.stderr)


def _show_hdb_warnings(ds) -> None:
    """What the HDB's reader or builder found doubtful (its ``warnings`` attribute), as warning lines."""
    from hydrolink.protocol.hdb.layout import hdb_warnings
    for note in hdb_warnings(ds):
        _show_warning(note, UserWarning, "", 0)


@cli.group()
def hdb() -> None:
    """Hydrodynamic databases: build with Capytaine, inspect any supported format."""


@hdb.command("build")
@click.argument("spec", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="NetCDF file to write (hydrolink's HDB layout).")
@click.option("--no-progress", is_flag=True, help="Hide the progress bar.")
def hdb_build(spec: Path, output: Path, no_progress: bool) -> None:
    """Compute an HDB with Capytaine from a build SPEC (TOML); cached by its inputs."""
    from hydrolink.server.hdb.build.builder import build_hdb
    from hydrolink.protocol.hdb.schema import hdb_dofs, to_netcdf

    ds = _guard(build_hdb, spec, progress=not no_progress, free_surface=True)
    _show_hdb_warnings(ds)
    output.parent.mkdir(parents=True, exist_ok=True)
    to_netcdf(ds, output)
    click.echo(f"wrote {output} ({ds.sizes['omega']} frequencies, bodies {list(map(str, ds['body'].values))})")
    for body, names in hdb_dofs(ds).mode_map().items():
        click.echo(f"  {body}: generalized modes {', '.join(names)} (docs/generalized-modes.md)")
    if "free_surface_file" in ds.attrs:
        click.echo(f"free-surface solution for hydrolink view: {ds.attrs['free_surface_file']}")


@hdb.command("info")
@click.argument("file", type=click.Path(path_type=Path))
@click.option("--plot", type=click.Path(dir_okay=False, path_type=Path), help="Write a PNG of A, B, |F_ex|, K(t).")
@click.option("--dofs", help="Comma-separated DOFs to plot (default: all with data).")
@click.option("--convention", type=click.Choice(["exp(-iwt)", "exp(+iwt)"]),
              help="Time convention of a Capytaine-layout file's complex amplitudes, when the file does not "
                   "declare it (default Capytaine's exp(-iwt); WecOptTool writes exp(+iwt)).")
def hdb_info(file: Path, plot: Path | None, dofs: str | None, convention: str | None) -> None:
    """Summarise an HDB (Capytaine .nc, BEMIO .h5, WAMIT .1/.3/.hst, hydrolink .nc)."""
    from hydrolink.server.hdb.info import hdb_summary, plot_hdb
    from hydrolink.server.hdb.io import load_hdb

    ds = _guard(load_hdb, file, convention=convention)
    _show_hdb_warnings(ds)
    click.echo(hdb_summary(ds))
    if plot:
        _guard(plot_hdb, ds, plot, dofs=dofs.split(",") if dofs else None)
        click.echo(f"plot written to {plot}")


@hdb.command("modes")
@click.argument("scene_file", type=click.Path(dir_okay=False, path_type=Path))
def hdb_modes(scene_file: Path) -> None:
    """Print the [bodies.modes] table (modal mass, stiffness, damping) of each body of SCENE_FILE whose
    HDB is a WAMIT run with generalized modes, from the run's .mmx external force matrices."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.hdb.schema import hdb_dofs
    from hydrolink.protocol.scene import load_scene, resolve_path
    from hydrolink.server.hdb.wamit.modal_structure import modes_table

    scene, _ = _guard(load_scene, scene_file)
    hdbs = _guard(load_scene_hdbs, scene, scene_file, progress=False)
    found = False
    for i, body in enumerate(scene.bodies):
        path = resolve_path(scene_file, body.hdb) if body.hdb else None
        if path is None or path.suffix != ".1" or not hdb_dofs(hdbs[body.hdb]).has_modes:
            continue
        dofs = hdb_dofs(hdbs[body.hdb])
        if dofs.of(body.hdb_body_name):
            click.echo(f"# bodies[{i}] ({body.name})\n" + _guard(modes_table, path.with_suffix(".mmx"), dofs,
                                                                  body.hdb_body_name))
            found = True
    if not found:
        raise click.ClickException(f"{scene_file}: no body has a WAMIT HDB (.1) with generalized modes")


def _build_plant(scene, hdbs):
    """clients/analysis/plant.py's build_plant, imported when a controller first asks for a plant
    (its imports would add ~0.7 s to every hydrolink serve start)."""
    from hydrolink.clients.analysis.plant import build_plant
    return build_plant(scene, hdbs)


@cli.command()
@click.option("--bind", default="tcp://127.0.0.1:5555", show_default=True, envvar="HYDROLINK_BIND",
              help="ZeroMQ endpoint to bind (tcp://HOST:PORT or ipc://PATH); env HYDROLINK_BIND.")
@click.option("--session-timeout", default=300.0, show_default=True, type=Seconds(),
              help="Seconds before an idle session is dropped.")
@click.option("--cpu", type=int, help="Pin the process to this CPU (Linux); see README 'Performance'.")
@click.option("--curve-secret", type=click.Path(dir_okay=False, path_type=Path), envvar="HYDROLINK_CURVE_SECRET",
              help="Require CURVE (authentication + encryption) with this server .key_secret file; "
                   "env HYDROLINK_CURVE_SECRET.")
@click.option("--curve-clients", type=click.Path(file_okay=False, path_type=Path), envvar="HYDROLINK_CURVE_CLIENTS",
              help="Directory of the allowed clients' public .key files (with --curve-secret); "
                   "env HYDROLINK_CURVE_CLIENTS.")
@click.option("--key-file", type=click.Path(dir_okay=False, path_type=Path), envvar="HYDROLINK_KEY_FILE",
              help="Shared HMAC key file: every request must be signed with it (SPEC §3.3); "
                   "env HYDROLINK_KEY_FILE.")
@click.option("--store", type=click.Path(file_okay=False, path_type=Path),
              help="Folder of the HDB content store (files sent by hash, SPEC §5.8); default "
                   "$HYDROLINK_HDB_STORE, else $HYDROLINK_CACHE/hdb_store, else ~/.cache/hydrolink/hdb_store.")
@click.option("--store-mib", default=4096, show_default=True, type=click.IntRange(min=1),
              help="Bound of the HDB content store on disk, MiB (least recently used contents leave first).")
@click.option("--max-message-mib", type=click.IntRange(1, 4096),
              help="Largest message received, MiB over all its frames (SPEC §1; default 64, the protocol's "
                   "codec.MAX_MESSAGE_BYTES): a larger message is answered with error 1 naming the limit, unread; "
                   "a single frame over twice the limit is refused by ZeroMQ from its header (its connection is "
                   "dropped, no reply). Large HDBs: send their files by hash (run --hdb-files), each file one "
                   "upload under the limit, or raise it.")
@click.option("--max-setups", default=MAX_SETUPS, show_default=True, type=click.IntRange(min=1),
              help="Multibody hellos being set up (waiting for a worker or running) at once; one more is "
                   "refused at once with error 14 busy (SPEC §4.2): each holds its message and builds a model.")
@click.option("--max-sessions", default=MAX_SESSIONS, show_default=True, type=click.IntRange(min=1),
              help="Sessions open or being set up; one more multibody hello is refused at once with error 14 "
                   "busy (a session holds its model until bye or --session-timeout).")
@click.option("--max-memory-mib", type=click.IntRange(min=1), default=None,
              help="What the open sessions' models may hold together (MiB; default half the machine's memory): a "
                   "hello whose model would pass it is refused busy (memory), naming the figures.")
@click.option("--isolate-step-ms", default=ISOLATE_STEP_S * 1e3, show_default=True,
              type=Seconds(open_minimum=False, unit=1e-3),
              help="A session whose model's step takes longer (timed at set-up) steps in a worker process of its "
                   "own, off the loop that answers the others (0: every session).")
@click.option("--max-workers", default=MAX_WORKERS, show_default=True, type=click.IntRange(min=1),
              help="Worker processes (heavy sessions) at once; one more heavy hello is refused busy (workers).")
@click.option("--direct-port", type=click.IntRange(1, 65535), envvar="HYDROLINK_DIRECT_PORT",
              help="TCP port of the direct channel offered to the multibody clients and controllers (SPEC §5.7.5: "
                   "no ZeroMQ I/O thread on the step), on the --bind host; publish it beside the ZeroMQ port, with "
                   "the same number, from a container. Default: a free port (a Unix socket when --bind is on "
                   "loopback). A client stays on ZeroMQ when it cannot reach the port (not published, a firewall), "
                   "for a paced session (realtime), with CURVE (no direct channel: the port is unused) and with "
                   "hydrolink control --no-direct; env HYDROLINK_DIRECT_PORT.")
def serve(bind: str, session_timeout: float, cpu: int | None, curve_secret: Path | None,
          curve_clients: Path | None, key_file: Path | None, store: Path | None, store_mib: int,
          max_message_mib: int | None, max_setups: int, max_sessions: int, max_memory_mib: int | None,
          isolate_step_ms: float, max_workers: int, direct_port: int | None) -> None:
    """Run the force server until interrupted (SIGINT or SIGTERM)."""
    _pin_to_cpu(cpu)
    try:
        key = _hmac_key(key_file)
    except _UserError as exc:   # a bad --key-file: one line naming the file and why, status 2 (a bad option)
        exc.exit_code = 2
        raise
    from hydrolink.protocol.security import CurveKeyError, server_keys
    try:
        curve = server_keys(curve_secret, curve_clients)
    except CurveKeyError as exc:
        raise _UserError(str(exc)) from None
    # the server's modules after the options' own checks: a bad --cpu, --key-file or CURVE option is
    # said without importing them (about 2 s of CPU)
    import signal

    from hydrolink.protocol import codec
    from hydrolink.server.hdb.store import ContentStore, default_folder
    from hydrolink.server.processes import WARM_CHILDREN_S
    from hydrolink.server.service.direct import DirectError
    from hydrolink.server.service.force_server import BindError, ForceServer

    try:
        server = ForceServer(bind, session_timeout=session_timeout, key=key, curve=curve,
                             store=ContentStore(store or default_folder(), disk_bytes=store_mib * 2**20),
                             max_message_bytes=codec.MAX_MESSAGE_BYTES if max_message_mib is None
                             else max_message_mib * 2**20, max_setups=max_setups, max_sessions=max_sessions,
                             max_memory_bytes=(max_memory_mib or default_memory_mib()) * 2**20,
                             isolate_step_s=isolate_step_ms / 1e3, max_workers=max_workers,
                             plant_builder=_build_plant, direct_port=direct_port, children_after_s=WARM_CHILDREN_S)
    except BindError as exc:     # --bind in use or not this host's: one line, status 2 (a bad option)
        error = _UserError(f"--bind: {exc}")
        error.exit_code = 2
        raise error from None
    except DirectError as exc:   # --direct-port in use, or not on tcp://: one line, status 2 (a bad option)
        error = _UserError(f"--direct-port: {exc}")
        error.exit_code = 2
        raise error from None
    import gc
    gc.collect()
    gc.freeze()   # the start-up's ~100,000 objects (modules) out of later collections: a full one during a
    # set-up holds the GIL, and the loop, 24-48 instead of ~100 ms CPU (the served step itself collects nothing)
    signal.signal(signal.SIGTERM, lambda signum, frame: server.stop())  # docker stop
    secure = (" (CURVE: authenticated and encrypted)" if curve_secret else "") + \
        (" (every message signed: HMAC key file)" if key else "") + \
        ("" if direct_port is None else f" (--direct-port {direct_port} unused: no direct channel beside CURVE)"
         if curve_secret else f" (direct channel on TCP port {direct_port})")
    click.echo(f"hydrolink force server listening on {server.address}{secure}", err=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.close()


def _curve_options(func):
    """--curve-server-key / --curve-secret for a client of a CURVE server."""
    func = click.option("--curve-secret", type=click.Path(dir_okay=False, path_type=Path),
                        envvar="HYDROLINK_CURVE_SECRET",
                        help="This client's .key_secret file (CURVE); env HYDROLINK_CURVE_SECRET.")(func)
    return click.option("--curve-server-key", type=click.Path(dir_okay=False, path_type=Path),
                        envvar="HYDROLINK_CURVE_SERVER_KEY",
                        help="The server's public .key file (CURVE); env HYDROLINK_CURVE_SERVER_KEY.")(func)


def _key_file_option(func):
    """--key-file for a client of a signing server."""
    return click.option("--key-file", type=click.Path(dir_okay=False, path_type=Path), envvar="HYDROLINK_KEY_FILE",
                        help="The server's shared HMAC key file: every message signed (SPEC §3.3); "
                             "env HYDROLINK_KEY_FILE.")(func)


def _hmac_key(path: Path | None) -> bytes | None:
    if path is None:
        return None
    from hydrolink.protocol.security import CurveKeyError, read_hmac_key
    try:
        return read_hmac_key(path)
    except CurveKeyError as exc:
        raise _UserError(str(exc)) from None


def _client_keys(server_key: Path | None, secret: Path | None):
    if server_key is None and secret is None:   # no CURVE: zmq.auth's thread (asyncio, ~0.1 s) not imported
        return None
    from hydrolink.protocol.security import CurveKeyError, client_keys
    try:
        return client_keys(server_key, secret)
    except CurveKeyError as exc:
        raise _UserError(str(exc)) from None


@cli.group()
def keys() -> None:
    """Keys: CURVE key pairs (`new`) and shared HMAC signing keys (`hmac`)."""


@keys.command("hmac")
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
def keys_hmac(file: Path) -> None:
    """Write a new shared HMAC key to FILE (owner-only): give it to `serve`, `run`, `control` with --key-file."""
    from hydrolink.protocol.security import CurveKeyError, new_hmac_key
    try:
        click.echo(f"wrote {new_hmac_key(file)} (keep it secret; the server and its clients share it)")
    except CurveKeyError as exc:
        raise _UserError(str(exc)) from None


@keys.command("new")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
@click.option("--name", default="hydrolink", show_default=True, help="Base name of the two files.")
def keys_new(directory: Path, name: str) -> None:
    """Write NAME.key (public: give it to the other side) and NAME.key_secret (keep it) in DIRECTORY."""
    from hydrolink.protocol.security import new_key_pair

    if (directory / f"{name}.key_secret").exists():
        raise _UserError(f"{directory / (name + '.key_secret')} exists: choose another --name or directory")
    public, secret = new_key_pair(directory, name)
    click.echo(f"wrote {public} (public) and {secret} (secret)")


@cli.command()
@click.argument("scene", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Results NetCDF (default: SCENE with .out.nc).")
@click.option("--server", help="Address of a running force server; default: start an embedded one.")
@click.option("--no-progress", is_flag=True, help="Hide the progress bar.")
@click.option("--cpu", type=int, help="Pin the process to this CPU (Linux); see README 'Performance'.")
@click.option("--listen", default="tcp://127.0.0.1:*", show_default=True,
              help="With [[controllers]] and no --server: where the run's own force server listens.")
@click.option("--link-timeout", default=10.0, show_default=True, type=Seconds(),
              help="With --server: seconds the link may stay down (an outage) before the run ends, its rows kept.")
@click.option("--reply-timeout", default=60.0, show_default=True, type=Seconds(),
              envvar="HYDROLINK_REPLY_TIMEOUT",
              help="Seconds to wait for each reply of the server, a hello's set-up included (a big scene on a "
                   "busy shared server may need more; also $HYDROLINK_REPLY_TIMEOUT).")
@click.option("--hdb-files", is_flag=True,
              help="With --server: send each HDB file as itself, by SHA-256 (SPEC §5.8): the server reads it and "
                   "keeps it, so only what it lacks is uploaded, once. Default: the converted HDB every run.")
@click.option("--realtime", "realtime", type=click.FloatRange(*FACTOR_RANGE), is_flag=False, flag_value=1.0,
              default=None, metavar="[FACTOR]",
              help="Release each exchange at its wall-clock time, FACTOR x wall clock (default 1); overruns "
                   "and step latencies are reported (docs/realtime.md).")
@click.option("--control-token", envvar="HYDROLINK_CONTROL_TOKEN", metavar="TOKEN",
              help="With [[controllers]]: the secret they show to join (32-128 characters A-Z a-z 0-9 - _; "
                   "also $HYDROLINK_CONTROL_TOKEN). Default: the server draws one, printed with the join command.")
@click.option("--rt-priority", type=int, metavar="N", help=RT_PRIORITY_HELP)
@_curve_options
@_key_file_option
def run(scene: Path, output: Path | None, server: str | None, no_progress: bool, cpu: int | None,
        listen: str, link_timeout: float, reply_timeout: float, hdb_files: bool, realtime: float | None, control_token: str | None,
        rt_priority: int | None, curve_server_key: Path | None, curve_secret: Path | None, key_file: Path | None) -> None:
    """Co-simulate a SCENE (TOML) in lockstep with the force server."""
    _pin_to_cpu(cpu)
    _check_rt_priority(rt_priority)
    curve = _client_keys(curve_server_key, curve_secret)
    if curve is not None and server is None:
        raise _UserError("--curve-server-key/--curve-secret are for a remote server: give --server")
    if hdb_files and server is None:
        raise _UserError("--hdb-files is for a remote server (the embedded one reads the files itself): give --server")
    key = _hmac_key(key_file)
    # the run's modules after the options' own checks: a bad option is said without importing them
    # (about 2 s of CPU)
    from hydrolink.clients.run import run_scene_file

    import signal

    def _terminate(signum, frame):  # docker stop / kill: stop like Ctrl-C so the file is finalised
        raise KeyboardInterrupt(f"terminated by signal {signum}")

    signal.signal(signal.SIGTERM, _terminate)
    try:
        summary = _guard(run_scene_file, scene, output, server=server, progress=not no_progress, listen=listen,
                         key=key, link_timeout=link_timeout, timeout=reply_timeout, hdb_files=hdb_files,
                         realtime=realtime, control_token=control_token, rt_priority=rt_priority,
                         **({"curve": curve} if curve is not None else {}))
    except KeyboardInterrupt as exc:
        click.echo(f"hydrolink run: {exc or 'interrupted'}", err=True)
        raise SystemExit(130) from None
    steps, wall = summary.steps, summary.wall_time
    click.echo(f"wrote {summary.output}: {steps} steps in {wall:.2f} s ({steps / max(wall, 1e-9):.0f} steps/s; "
               f"server compute {(summary.server_compute_us_per_step or float('nan')):.1f} us/step)")
    headline = run_headline(summary.output)
    if headline:
        click.echo(headline)
    if summary.metrics is not None:   # a scene with limits: the WECCCOMP metrics after the ramp
        m = summary.metrics
        click.echo(f"WECCCOMP metrics: mean power {m.mean_power:.6g} W, peak-to-average {m.peak_to_average:.3g}; "
                   + ", ".join(f"{u.label} {100 * u.utilisation:.1f} % of {u.bound:g}"
                               + (f" ({u.violations} over)" if u.violations else "") for u in m.limits)
                   + (f"; electrical {m.electrical_power:.6g} W at efficiency {m.efficiency:g}" if m.efficiency < 1 else ""))
    if summary.realtime is not None:
        rt = summary.realtime
        click.echo(f"paced at {rt.factor:g}x wall clock ({1e3 * rt.period:.3g} ms per exchange): step latency "
                   f"p50 {1e3 * rt.latency_p50:.3f} ms, p99 {1e3 * rt.latency_p99:.3f} ms, max "
                   f"{1e3 * rt.latency_max:.3f} ms; {rt.overruns} overrun(s) of {rt.steps} steps"
                   + (f", worst {1e3 * rt.worst_lateness:.3f} ms late" if rt.overruns else ""))
        if getattr(rt, "parts_mean", None):   # a client's paced run (protocol/pacing.py PacedRunReport)
            click.echo("where a step's time went (mean / max ms): " + ", ".join(
                f"{part} {1e3 * rt.parts_mean[part]:.3f} / {1e3 * rt.parts_max.get(part, 0.0):.3f}"
                for part in rt.parts_mean)
                + ("; overruns by cause: " + ", ".join(f"{c} {n}" for c, n in rt.overrun_causes.items() if n)
                   if rt.overruns else ""))
    if hdb_files:
        click.echo(f"HDB files sent by hash: {summary.hdb_uploads} content(s) uploaded, the rest held by the server")
    for report in summary.moordyn or []:
        for body, offset in zip(report["bodies"], report["static_offset"] or []):
            click.echo(f"MoorDyn {report['mooring']!r}: {body}'s moored equilibrium is "
                       f"[{', '.join(f'{x:.4g}' for x in offset)}] (m, rad) from its reference position "
                       f"(initial_displacement to start there)")


@cli.command()
@click.argument("file", type=click.Path(dir_okay=False, exists=True, path_type=Path))
@click.option("--server", required=True, help="Force server hosting the session, e.g. tcp://HOST:PORT.")
@click.option("--token", envvar="HYDROLINK_CONTROL_TOKEN", required=True, metavar="TOKEN",
              help="The session's join token (hydrolink run prints it, or takes it from --control-token; also "
                   "$HYDROLINK_CONTROL_TOKEN): the server refuses a controller without it.")
@click.option("--session", help="Session id (default: the open session holding the token and declaring this "
                                "controller).")
@click.option("--name", help="The scene's controllers[i].name (default: the class's name attribute).")
@click.option("--class", "class_name", help="Controller class in FILE, when it defines several.")
@click.option("--join-wait", default=30.0, show_default=True, type=Seconds(open_minimum=False),
              help="Seconds to keep trying to join.")
@click.option("--no-direct", is_flag=True, help="Stay on ZeroMQ even when the server offers its direct channel "
                                                 "(SPEC §5.7.5: a plain socket, a faster round trip at 1 kHz).")
@click.option("--rt-priority", type=int, metavar="N", help=RT_PRIORITY_HELP)
@_curve_options
@_key_file_option
def control(file: Path, server: str, token: str, session: str | None, name: str | None, class_name: str | None,
            join_wait: float, no_direct: bool, rt_priority: int | None, curve_server_key: Path | None,
            curve_secret: Path | None, key_file: Path | None) -> None:
    """Run the Python controller in FILE (a hydrolink.clients.control.Controller subclass)."""
    _check_rt_priority(rt_priority)
    from hydrolink.clients.control import ControllerError, load_controller, run_controller

    curve = _client_keys(curve_server_key, curve_secret)
    try:
        stats = run_controller(load_controller(file, class_name), server, token=token, session=session, name=name,
                               join_wait=join_wait, curve=curve, key=_hmac_key(key_file), direct=not no_direct,
                               rt_priority=rt_priority)
    except ControllerError as exc:
        raise _UserError(str(exc)) from None
    except KeyboardInterrupt:
        raise SystemExit(130) from None
    cpu = f"; {1e6 * stats['cpu_s'] / stats['steps']:.0f} µs CPU a step" if stats["steps"] else ""
    click.echo(f"controller done: {stats['steps']} steps, {stats['errors']} errors"
               + (" (over the direct channel" + (", binary frames" if stats["frames"] else "") if stats["direct"]
                  else " (over ZeroMQ") + cpu + ")", err=True)


def _analysis(fn, scene: Path, *args, **kwargs):
    """Run an analysis of SCENE (steady, linearize, optimize): its SteadyError as the user's error
    naming the file, its notes on stderr; returns its summary."""
    from hydrolink.clients.analysis.steady import SteadyError

    try:
        out = _guard(fn, scene, *args, **kwargs)
    except SteadyError as exc:
        raise _UserError(f"{scene}: {exc}") from None
    for note in (out["warnings"] if isinstance(out, dict) else out.warnings):
        click.echo(f"note: {note}", err=True)
    return out


@cli.command()
@click.argument("scene", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Results NetCDF, one period (default: SCENE with .steady.nc).")
@click.option("--order", type=click.IntRange(1, 200), help="Harmonics N (2N+1 collocation points); default [steady] order.")
@click.option("--formulation", type=click.Choice(["dae", "ode"]), help="Default [steady] formulation.")
@click.option("--dt", type=click.FloatRange(min=0, min_open=True), help="Output sampling (default simulation.dt).")
@click.option("--no-progress", is_flag=True, help="Hide the HDB build progress bar.")
def steady(scene: Path, output: Path | None, order: int | None, formulation: str | None, dt: float | None,
           no_progress: bool) -> None:
    """Periodic steady state of a SCENE in regular waves by pseudo-spectral collocation (docs/steady.md)."""
    from hydrolink.clients.analysis.steady import steady_scene_file

    s = _analysis(steady_scene_file, scene, output, order=order, formulation=formulation, dt=dt,
                  progress=not no_progress)
    click.echo(f"wrote {s['output']}: one period, {s['rows']} rows; order {s['order']} ({s['formulation']}, "
               f"{s['unknowns']} unknowns), {s['iterations']} Newton iteration(s), residual {s['residual']:.1e}, "
               f"solve {1e3 * s['solve_seconds']:.1f} ms")


@cli.command()
@click.argument("scene", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path),
              help="Results NetCDF, one (repeat) period (default: SCENE with .optimal.nc).")
@click.option("--dt", type=click.FloatRange(min=0, min_open=True), help="Output sampling (default simulation.dt).")
@click.option("--no-progress", is_flag=True, help="Hide the HDB build progress bar.")
def optimize(scene: Path, output: Path | None, dt: float | None, no_progress: bool) -> None:
    """PTO forces maximising the mean absorbed power of SCENE under its [optimize] limits (docs/optimal-control.md)."""
    from hydrolink.clients.analysis.optimal.run import optimize_scene_file

    s = _analysis(optimize_scene_file, scene, output, dt=dt, progress=not no_progress)
    click.echo(f"wrote {s.output}: optimum {s.power:.6g} W = {100 * s.power / s.unconstrained_power:.1f} % of the "
               f"unconstrained bound {s.unconstrained_power:.6g} W (period {s.period:.4g} s, order {s.order}, "
               f"{s.solver} {s.status}, {1e3 * s.solve_seconds:.0f} ms)")
    for use in s.metrics.limits:
        click.echo(f"  {use.label}: {100 * use.utilisation:.1f} % of {use.bound:g}"
                   + (" (active)" if use.label in s.active else ""))
    click.echo(f"  peak-to-average power {s.metrics.peak_to_average:.3g}")
    if s.metrics.efficiency < 1:
        click.echo(f"  electrical power {s.metrics.electrical_power:.6g} W at efficiency {s.metrics.efficiency:g} "
                   "(the quantity maximised)")


@cli.command()
@click.argument("scene", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="The plant: .npz (A, B, C, D, states, inputs, outputs), .mat (MATLAB) or .nc.")
@click.option("--dt", type=click.FloatRange(min=0, min_open=True),
              help="Discretise at DT s (zero-order hold); default: continuous time.")
@click.option("--no-progress", is_flag=True, help="Hide the HDB build progress bar.")
def linearize(scene: Path, output: Path, dt: float | None, no_progress: bool) -> None:
    """The device of SCENE as a linear state-space plant about its equilibrium (docs/plant.md)."""
    from hydrolink.clients.analysis.plant import linearize_scene_file

    p = _analysis(linearize_scene_file, scene, output, dt=dt, progress=not no_progress)
    kind = "continuous" if p.dt is None else f"discrete, dt = {p.dt:g} s (zero-order hold)"
    click.echo(f"wrote {output}: {len(p.states)} states ({len(p.states) - sum(s.startswith('radiation:') for s in p.states)}"
               f" mechanical), {len(p.inputs)} inputs, {len(p.outputs)} outputs, {kind}")


@cli.group()
def bench() -> None:
    """Measure a scene's options: hydrolink bench accuracy SCENE.toml (docs/accuracy.md)."""


@bench.command("accuracy")
@click.argument("scene", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--grid", "grid_file", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="TOML grid of options (clients/studies/accuracy.py); combined with the flags below.")
@click.option("--dt", help="Comma-separated simulation.dt values.")
@click.option("--irf-duration", help="Comma-separated hydro.irf_duration values (s).")
@click.option("--radiation", help="Comma-separated hydro.radiation methods.")
@click.option("--excitation", help="Comma-separated waves.excitation methods.")
@click.option("--coupling", help="Comma-separated coupling.scheme values.")
@click.option("--reduce", help="Comma-separated client.reduce values: true,false measures reduced bodies "
                               "against the full rigid-body form (same results, per-step cost).")
@click.option("--nonlinear", help="Comma-separated hydro.nonlinear modes (none, hydrostatic, froude-krylov).")
@click.option("--ref", "refs", multiple=True, help="Reference setting KEY=VALUE (repeatable), e.g. dt=0.005.")
@click.option("--mode", type=click.Choice(["axes", "product"]), help="One key at a time (default) or all combinations.")
@click.option("--duration", type=float, help="Simulated seconds of every run (default: the scene's).")
@click.option("--window", nargs=2, type=float, help="Comparison window START END (s).")
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path), default=Path("accuracy"),
              show_default=True, help="Folder for accuracy.md, accuracy.png, accuracy.csv.")
@click.option("--title", help="Title of the table and plot (default: the scene's name).")
@click.option("--keep-runs", is_flag=True, help="Keep every run's scene and results in OUTPUT/runs.")
@click.option("--repeat", type=click.IntRange(1, 20), default=1, show_default=True,
              help="Runs per option; the cheapest wall time counts (a busy machine only adds time).")
def bench_accuracy_cmd(scene: Path, grid_file: Path | None, dt, irf_duration, radiation, excitation, coupling,
                       reduce, nonlinear, refs, mode, duration, window, output: Path, title, keep_runs: bool,
                       repeat: int) -> None:
    """Run SCENE under a grid of options against a reference run; table + plots of error vs cost."""
    from hydrolink.clients.studies.accuracy import BenchError, Grid, bench_accuracy, grid_from_flags

    try:
        base = Grid.from_toml(grid_file) if grid_file else None
        grid = grid_from_flags(base, {"dt": dt, "irf_duration": irf_duration, "radiation": radiation,
                                      "excitation": excitation, "coupling": coupling, "reduce": reduce,
                                      "nonlinear": nonlinear},
                               refs, mode, duration,
                               tuple(window) if window else None)
    except BenchError as exc:
        raise _UserError(str(exc)) from None
    rows = _guard(bench_accuracy, scene, grid, output, title=title, keep_runs=keep_runs, repeat=repeat,
                  log=lambda m: click.echo(m, err=True))
    front = [r["label"] for r in rows if r["front_rms_error_us_per_step"]]
    click.echo(f"wrote {output / 'accuracy.md'}, {output / 'accuracy.png'}: {len(rows) - 1} options; "
               f"Pareto front (RMS error vs us/step): {front}")


@cli.command("sweep")
@click.argument("sweep_file", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path),
              help="Output folder (default: the sweep file's name, in the current folder); a folder of an "
                   "earlier run of the same sweep is resumed: its finished cases are not run again.")
@click.option("--workers", type=click.IntRange(1, 4096),
              help="Local worker processes (one thread each); default: the CPUs this process may use.")
@click.option("--scheduler", help="Address of a running Dask scheduler (tcp://HOST:8786) instead of local workers.")
@click.option("--retry-failed", is_flag=True, help="Run the cases that failed in an earlier run again.")
@click.option("--no-progress", is_flag=True, help="Hide the progress bar.")
def sweep_cmd(sweep_file: Path, output: Path | None, workers: int | None, scheduler: str | None, retry_failed: bool,
              no_progress: bool) -> None:
    """Run every case of a SWEEP_FILE (TOML: a scene and a grid of its keys) on Dask; writes each
    case's results, sweep.nc (one dimension per swept key), the power matrix / AEP and plots (docs/sweeps.md)."""
    from hydrolink.clients.studies.power_matrix import PowerMatrixError
    from hydrolink.clients.studies.sweep import SweepError, run_sweep

    if workers and scheduler:
        raise _UserError("--workers and --scheduler: give one (the scheduler's workers are its own)")
    try:
        report = _guard(run_sweep, sweep_file, output or Path(sweep_file.stem), workers=workers, scheduler=scheduler,
                        retry_failed=retry_failed, progress=not no_progress, log_line=lambda m: click.echo(m, err=True))
    except (SweepError, PowerMatrixError) as exc:
        raise _UserError(str(exc)) from None
    except KeyboardInterrupt:
        click.echo("hydrolink sweep: interrupted (finished cases are kept; run the same command to resume)", err=True)
        raise SystemExit(130) from None
    for note in report.notes:
        click.echo(f"note: {note}", err=True)
    for line in report.annual_energy:
        click.echo(line)
    failed = f", {len(report.failed)} failed: {report.failed[:5]}{' ...' if len(report.failed) > 5 else ''}" \
        if report.failed else ""
    retried = f", {report.retried} re-run after a worker died" if report.retried else ""
    click.echo(f"wrote {report.outdir}: {report.cases} cases ({report.skipped} finished before, {report.run} run"
               f"{retried}{failed}) in {report.wall_time:.1f} s; {', '.join(Path(p).name for p in report.outputs)}")


@cli.group()
def fmu() -> None:
    """FMI co-simulation: export hydrolink's forces as an FMU (import: [client] type = "fmu" in a scene)."""


@fmu.command("export")
@click.argument("scene", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="FMU file to write (co-simulation).")
@click.option("--native/--python", default=True, show_default=True,
              help="--native (default): a C binary, no Python where it is imported, FMI 2.0 or 3.0, state "
                   "save/restore; it needs a running hydrolink serve. --python: pythonfmu, FMI 2.0, needs a Python "
                   "with hydrolink where it is imported, and can embed its server (server_address \"\").")
@click.option("--fmi", type=click.Choice(["2", "3"]), default="2", show_default=True,
              help="FMI version of a --native FMU (2.0 is what every importer takes; 3.0 for FMI 3 masters).")
def fmu_export(scene: Path, output: Path, native: bool, fmi: str) -> None:
    """Export the SCENE's hydrodynamic forces as an FMU (inputs: body states; outputs: forces)."""
    if native:
        from hydrolink.clients.fmu.native import NativeFMUError, export_native_fmu
        try:
            path, notes = _guard(export_native_fmu, scene, output, fmi=int(fmi))
        except NativeFMUError as exc:
            raise _UserError(str(exc)) from None
    elif fmi != "2":
        raise _UserError("--python FMUs are FMI 2.0 only (use --native for FMI 3.0)")
    else:
        from hydrolink.clients.fmu.export import export_fmu
        path, notes = _guard(export_fmu, scene, output)
    for note in notes:
        click.echo(f"note: {note}", err=True)
    click.echo(f"wrote {path}")


@cli.command()
@click.argument("results", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder of the ParaView series (one transient .vtkhdf file per part).")
@click.option("--scene-dir", type=click.Path(file_okay=False, path_type=Path),
              help="Folder the results' scene paths (HDBs, meshes) are relative to (default: the results file's).")
@click.option("--start", type=float, help="First time shown (s).")
@click.option("--end", type=float, help="Last time shown (s).")
@click.option("--stride", type=click.IntRange(1), default=1, show_default=True, help="Every N-th row.")
@click.option("--grid-extent", type=float, nargs=4, help="Free-surface grid x0 x1 y0 y1 (m); default around the bodies.")
@click.option("--grid-cells", type=int, nargs=2, help="Free-surface grid cells nx ny (default 100 100).")
@click.option("--parts", default="bodies,surface,moorings,markers", show_default=True,
              help="Comma-separated parts to write.")
@click.option("--gif", "gif", is_flag=True, help="Also render OUTPUT/view.gif (matplotlib, headless).")
@click.option("--mp4", "mp4", is_flag=True, help="Also render OUTPUT/view.mp4 (needs ffmpeg).")
@click.option("--frames", "max_frames", type=click.IntRange(2), default=100, show_default=True,
              help="At most this many frames in the animation (evenly strided over the shown rows).")
@click.option("--no-progress", is_flag=True, help="Hide the progress bar.")
def view(results: Path, output: Path, scene_dir: Path | None, start: float | None, end: float | None, stride: int,
         grid_extent: tuple | None, grid_cells: tuple | None, parts: str, gif: bool, mp4: bool, max_frames: int,
         no_progress: bool) -> None:
    """A RESULTS file (run, steady or a sweep case) as a ParaView time series and an animation (docs/view.md)."""
    import numpy as np

    from hydrolink.clients.view.animation import animate
    from hydrolink.clients.view.frames import DEFAULT_CELLS, ViewOptions
    from hydrolink.clients.view.results import ViewError
    from hydrolink.clients.view.series import view_results

    try:
        options = ViewOptions(start=start, end=end, stride=stride, extent=tuple(grid_extent) if grid_extent else None,
                              cells=tuple(grid_cells) if grid_cells else DEFAULT_CELLS,
                              parts=tuple(p.strip() for p in parts.split(",") if p.strip()))
        summary, stage, rows = _guard(view_results, results, output, options, scene_dir=scene_dir,
                                      progress=not no_progress)
        movies = [output / f"view.{kind}" for kind, asked in (("gif", gif), ("mp4", mp4)) if asked]
        for movie in movies:
            picked = rows[np.linspace(0, rows.size - 1, min(rows.size, max_frames)).round().astype(int)]
            _guard(animate, stage, np.unique(picked), movie, progress=not no_progress)
    except ViewError as exc:
        raise _UserError(str(exc)) from None
    for note in summary.notes:
        click.echo(f"note: {note}", err=True)
    click.echo(f"wrote {summary.frames} frames to {output}/ in {summary.seconds:.1f} s: "
               + ", ".join(p.name for p in summary.files))
    for movie in movies:
        click.echo(f"wrote {movie}")
    click.echo(f"open in ParaView: paraview {' '.join(str(p) for p in summary.files)}  (File > Open, the "
               "VTKHDF reader; press Play for the time series)")


def main() -> None:
    """Console entry point.

    BLAS/OpenMP pools default to one thread (before numpy loads): the lockstep hot paths are small
    matrix-vector products, and a second BLAS thread competing with the other participant for a
    core made the server's convolution 20x slower on a 2-core machine. Set the variables to override."""
    import os
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    cli(prog_name="hydrolink")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
