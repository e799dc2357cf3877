"""What a WAMIT run's files state about the run, read and never assumed: g, ULEN, the water depth,
each body's XBODY, VCG, displaced volume, centre of buoyancy and name, and the meaning of the
numeric files' first column (IPEROUT).

Sources, first found:

* ``.out`` (the run's report): g, ULEN, depth, GDF names, XBODY, volumes, centres of buoyancy and
  gravity (VCG = Zg), the period list of the potential run;
* ``.mmx``: g, ULEN, volumes, centres of buoyancy and gravity, IALTFRC;
* ``.pot``: HBOT (<= 0: infinite depth), the GDF names and XBODY of each body;
* ``.frc`` (alternative form 1, IALTFRC = 1): each body's VCG;
* ``.cfg``: IPEROUT, IALTFRC (and GRAV, ULEN when written there), each body's generalized modes
  (NEWMDS, NEWMDS(k); a lone body's: every mode beyond its six);
* else the scene's ``bodies[i].wamit`` table (``stated``: ulen, gravity, depth, xbody, vcg, volume,
  iperout), for what no file states. A stated value a file contradicts is an error; what neither
  states is one error naming every missing value and the key that states it.

The first column (IPEROUT 1: period in s; 2: angular frequency in rad/s; 3: ω²L/g): the ``.cfg``'s
IPEROUT, else what the ``.out``'s period list shows (the ``.1``'s values matched against the listed
periods read each way), else the stated ``iperout``. A ``.cfg`` IPEROUT that the ``.out`` contradicts
is an error. Whatever IPEROUT, first-column values -1 and 0 mark the zero- and infinite-frequency
rows (WAMIT's infinite and zero periods).
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from hydrolink.protocol.hdb.layout import HDBError
from hydrolink.server.hdb.reader_warnings import HDBWarning

_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?"
# each fact: the scene key that states it (in bodies[i].wamit) and what it is
KEYS = {"ulen": ("ulen", "ULEN"), "g": ("gravity", "g"), "depth": ("depth", "water depth"),
        "xbody": ("xbody", "XBODY"), "vcg": ("vcg", "VCG"), "iperout": ("iperout", "IPEROUT"),
        "volume": ("volume", "displaced volume")}
IPEROUT_MEANING = {1: "periods in s", 2: "angular frequencies in rad/s", 3: "nondimensional ω²L/g"}


def _sibling(stem: Path, suffix: str) -> Path:
    return stem.with_name(stem.name + suffix)


def read_cfg(stem: Path) -> dict[str, str]:
    """KEY=value settings of the ``.cfg`` (upper-case keys), empty if there is none."""
    cfg = _sibling(stem, ".cfg")
    if not cfg.is_file():
        return {}
    out = {}
    key = r"[A-Za-z_]\w*(?:\(\s*\d+\s*\))?"   # NAME or NAME(k), e.g. NEWMDS(1)
    for match in re.finditer(rf"^\s*({key})\s*=\s*(\S+)", cfg.read_text(errors="replace"), re.M):
        out[match.group(1).upper()] = match.group(2)
    return out


def _floats(text: str) -> list[float]:
    return [float(v.replace("D", "E").replace("d", "e")) for v in re.findall(_FLOAT, text)]


def read_out(stem: Path) -> dict:
    """Run facts of the ``.out`` report (only the part before the first frequency's results)."""
    return _read_report(_sibling(stem, ".out"), stop=("Wave period", "Output from  WAMIT"))


def read_mmx(stem: Path) -> dict:
    """Run facts of the ``.mmx`` (g, ULEN, IALTFRC and each body's volume, centres of buoyancy and
    gravity) and ``modes``: the highest mode index of its external force matrices (0 without them)."""
    facts = _read_report(_sibling(stem, ".mmx"), stop=())
    if facts:
        rows = re.findall(r"^\s*(\d+)\s+(\d+)\s+" + _FLOAT, _sibling(stem, ".mmx").read_text(errors="replace"), re.M)
        facts["modes"] = max((max(int(i), int(j)) for i, j in rows), default=0)
    return facts


def _read_report(path: Path, stop: tuple[str, ...]) -> dict:
    if not path.is_file():
        return {}
    facts: dict = {"file": path.name, "gdf": [], "xbody": [], "volume": [], "cb": [], "cog": [], "periods": []}
    in_periods = False
    with path.open(errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            if any(s in line for s in stop):
                break
            try:
                in_periods = _report_line(line, facts, in_periods)
            except (ValueError, IndexError):
                raise HDBError(path.name, f"line {number}", f"cannot parse {line.strip()!r}") from None
    return facts


def _report_line(line: str, facts: dict, in_periods: bool) -> bool:
    """Take one line's fact into ``facts``; returns whether the period list goes on."""
    stripped = line.strip()
    if in_periods:
        tokens = stripped.split()
        if tokens and re.fullmatch(_FLOAT, tokens[0]):
            decimals = len(tokens[0].split(".")[1]) if "." in tokens[0] else 0
            facts["periods"].append((float(tokens[0]), 0.5 * 10.0 ** -decimals))
            return True
        return False
    if re.match(r"Period\s+Time\b", stripped):
        return True
    if m := re.search(r"N=\s*\d+\s+(\S+\.gdf)", line, re.I):
        facts["gdf"].append(Path(m.group(1)).stem)
    elif m := re.search(rf"Gravity:\s*({_FLOAT})", line):
        facts["g"] = float(m.group(1))
        if m2 := re.search(rf"Length scale:\s*({_FLOAT})", line):
            facts["ulen"] = float(m2.group(1))
    elif m := re.search(r"Water depth:\s*(\S+)", line):
        word = m.group(1)
        facts["depth"] = math.inf if word.lower().startswith("inf") else float(word)
    elif m := re.search(r"IALTFRC\s*=\s*(\d+)", line):
        facts["ialtfrc"] = int(m.group(1))
    elif "XBODY" in line and "=" in line:
        facts["xbody"].append([float(v) for v in re.findall(rf"=\s*({_FLOAT})", line)][:4])
    elif stripped.startswith("Volumes"):
        facts["volume"].append(_floats(stripped.split(":", 1)[1])[0])
    elif stripped.startswith("Center of Buoyancy"):
        facts["cb"].append(_floats(stripped.split(":", 1)[1])[:3])
    elif stripped.startswith("Center of Gravity"):
        facts["cog"].append(_floats(stripped.split(")", 1)[1])[:3])
    return False


def read_pot(stem: Path) -> dict:
    """HBOT and each body's GDF name and XBODY from the ``.pot`` (the line after each GDF name)."""
    path = _sibling(stem, ".pot")
    if not path.is_file():
        return {}
    lines = path.read_text(errors="replace").splitlines()
    facts: dict = {"file": path.name, "gdf": [], "xbody": []}
    try:
        hbot = _floats(lines[1])[0]
        facts["depth"] = math.inf if hbot <= 0 else hbot
        for n, line in enumerate(lines):
            tokens = line.split()
            if tokens and tokens[0].lower().endswith(".gdf") and n > 1:
                facts["gdf"].append(Path(tokens[0]).stem)
                n_xbody = n + 2
                facts["xbody"].append(_floats(lines[n + 1])[:4])
                if len(facts["xbody"][-1]) < 4:
                    raise ValueError
    except (ValueError, IndexError):
        where = "line 2 (HBOT)" if "depth" not in facts else f"line {n_xbody} (XBODY)"
        raise HDBError(path.name, where, "cannot parse: expected a number (HBOT) on line 2 and each body's "
                                         "XBODY(1-4) on the line after its GDF file name") from None
    return facts


def read_frc(stem: Path, n_bodies: int) -> dict:
    """Each body's VCG from an ``.frc`` of alternative form 1 (IOPTN line, then per body VCG and
    the 3 lines of XPRDCT)."""
    path = _sibling(stem, ".frc")
    if not path.is_file():
        return {}
    lines = [line for line in path.read_text(errors="replace").splitlines()[1:] if line.strip()]
    vcg = []
    try:
        for n in range(n_bodies):
            vcg.append(_floats(lines[1 + 4 * n])[0])
            if not all(len(_floats(lines[2 + 4 * n + k])) >= 3 for k in range(3)):
                raise ValueError
    except (ValueError, IndexError):
        raise HDBError(path.name, "VCG", f"not an .frc of alternative form 1 with {n_bodies} bodies (IOPTN, then "
                                         "per body VCG and the 3 lines of XPRDCT); another form: say which in the "
                                         ".cfg (IALTFRC = 2 or 3)") from None
    return {"file": path.name, "vcg": vcg}


@dataclass(frozen=True)
class RunFacts:
    """A run's facts in SI, each with where it was read (``origin``: fact -> file or scene key)."""
    g: float
    ulen: float
    depth: float
    iperout: int
    xbody: np.ndarray           # (N, 3)
    vcg: np.ndarray             # (N,)
    volume: np.ndarray | None   # (N,)
    cb: np.ndarray | None       # (N, 3) global frame
    names: list[str]
    origin: dict[str, str]
    modes: tuple[int, ...]      # (N,) each body's generalized modes (NEWMDS), after its rigid six

    @property
    def n_bodies(self) -> int:
        return len(self.names)


def _per_body(values: list, n: int) -> list | None:
    return values if values and len(values) == n else None


def _newmds(cfg: dict[str, str], cfg_name: str) -> dict[int, int]:
    """The ``.cfg``'s generalized-mode counts: body index (1-based; 0 for an unindexed NEWMDS) ->
    count."""
    out = {}
    for key, value in cfg.items():
        if m := re.fullmatch(r"NEWMDS(?:\(\s*(\d+)\s*\))?", key):
            try:
                count = int(value.rstrip(",;"))
            except ValueError:
                raise HDBError(cfg_name, key, f"not a mode count: {value!r}") from None
            if count < 0:
                raise HDBError(cfg_name, key, f"must be >= 0, got {count}")
            out[int(m.group(1) or 0)] = count
    return out


def _body_count(stem: Path, file1: Path, max_mode: int, listed: list[tuple[int, str]], cfg: dict[str, str],
                stated: Mapping, mmx_modes: int = 0) -> tuple[int, tuple[int, ...]]:
    """The run's number of bodies and each one's generalized modes (NEWMDS): the bodies as the
    files that list them say (``listed``: (count, file)), else the scene's ``wamit.xbody``, never
    guessed from the ``.1``'s mode count; the modes from the ``.cfg``'s NEWMDS / NEWMDS(k) (a lone
    body's from the mode count). Modes that do not add up to 6 per body plus the NEWMDS, or extra
    modes several bodies could own, are an error naming the file and the count (read as rigid
    bodies, modes 7-10 of a flexible barge would become a second body's surge..roll)."""
    cfg_name = _sibling(stem, ".cfg").name
    newmds = _newmds(cfg, cfg_name)
    counts = [(n, where) for n, where in listed if n > 0]
    if stated.get("xbody") is not None:
        counts.append((len(stated["xbody"]), "the scene's wamit.xbody"))
    extra = sum(newmds.values())
    if counts:
        n, where = max(counts)
    elif (max_mode - extra) % 6 == 0 and max_mode > extra:
        n, where = (max_mode - extra) // 6, f"{max_mode} modes less NEWMDS"
    else:
        raise HDBError(file1.name, "modes", f"{max_mode} modes, not 6 per body plus the .cfg's NEWMDS ({extra}), "
                                            "and no file (.out, .pot, .mmx) lists the run's bodies: state the "
                                            "bodies (wamit.xbody) or the generalized modes (NEWMDS in the .cfg)")
    if 0 in newmds and n > 1:
        raise HDBError(cfg_name, "NEWMDS", f"one count for the run's {n} bodies ({where}): give each body's as "
                                           "NEWMDS(k)")
    wrong = [k for k in newmds if k > n]
    if wrong:
        raise HDBError(cfg_name, f"NEWMDS({wrong[0]})", f"body {wrong[0]} of the run's {n} ({where})")
    modes = tuple(newmds.get(k + 1, newmds.get(0, 0)) for k in range(n))
    if not newmds and n == 1 and max_mode > 6:
        modes = (max_mode - 6,)            # a lone body owns every mode beyond its six
    if mmx_modes and n == 1 and mmx_modes != max_mode:
        raise HDBError(_sibling(stem, ".mmx").name, "External force matrices",
                       f"modes 1-{mmx_modes}, but {file1.name} holds modes 1-{max_mode}: the mode counts of the "
                       "files do not agree")
    if max_mode != 6 * n + sum(modes):
        said = f"the .cfg's NEWMDS {list(modes)}" if newmds else "no NEWMDS in the .cfg"
        raise HDBError(file1.name, "modes", f"modes 1-{max_mode} for the run's {n} bodies ({where}) and {said}: "
                                            f"{6 * n + sum(modes)} expected (6 per body plus its generalized "
                                            "modes); the mode counts of the files do not agree")
    return n, modes


def _file_facts(stem: Path, file1: Path, max_mode: int, cfg: dict[str, str],
                stated: Mapping) -> tuple[dict[str, tuple[object, str]], int]:
    """fact -> (value, file that states it), first found in the module docstring's order; and the
    number of bodies (:func:`_body_count`)."""
    out, mmx, pot = read_out(stem), read_mmx(stem), read_pot(stem)
    n_bodies, modes = _body_count(stem, file1, max_mode, [(len(r.get(k, [])), r.get("file", "")) for r, k in
                                                          ((out, "xbody"), (pot, "xbody"), (mmx, "volume"))], cfg,
                                  stated, mmx.get("modes", 0))
    found: dict[str, tuple[object, str]] = {"modes": (modes, _sibling(stem, ".cfg").name if any(modes) else file1.name)}

    def take(fact: str, value, source: str) -> None:
        if value is not None and fact not in found:
            found[fact] = (value, source)

    cfg_name = _sibling(stem, ".cfg").name
    for report in (out, mmx):
        if report:
            take("g", report.get("g"), report["file"])
            take("ulen", report.get("ulen"), report["file"])
            take("depth", report.get("depth"), report["file"])
            take("xbody", _per_body(report["xbody"], n_bodies), report["file"])
            take("volume", _per_body(report["volume"], n_bodies), report["file"])
            take("cb", _per_body(report["cb"], n_bodies), report["file"])
            cog = _per_body(report["cog"], n_bodies)
            take("vcg", [c[2] for c in cog] if cog else None, report["file"])
            take("names", _per_body(report["gdf"], n_bodies), report["file"])
            take("ialtfrc", report.get("ialtfrc"), report["file"])
    if pot:
        take("depth", pot["depth"], pot["file"])
        take("xbody", _per_body(pot["xbody"], n_bodies), pot["file"])
        take("names", _per_body(pot["gdf"], n_bodies), pot["file"])
    for key, fact, kind in (("GRAV", "g", float), ("ULEN", "ulen", float), ("IALTFRC", "ialtfrc", int),
                            ("IPEROUT", "iperout", int)):
        if key in cfg:
            try:
                take(fact, kind(cfg[key].rstrip(",;")), cfg_name)
            except ValueError:
                raise HDBError(cfg_name, key, f"not a number: {cfg[key]!r}") from None
    if "vcg" not in found and found.get("ialtfrc", (1,))[0] == 1:
        frc = read_frc(stem, n_bodies)
        take("vcg", frc.get("vcg"), frc.get("file", ""))
    if out.get("periods"):
        found["out_periods"] = (out["periods"], out["file"])
    return found, n_bodies


def _agree(a, b) -> bool:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape:
        return False
    both_inf = np.isinf(a) & np.isinf(b) & (np.sign(a) == np.sign(b))
    close = np.isclose(np.where(both_inf, 0, a), np.where(both_inf, 0, b), rtol=1e-5, atol=1e-4)
    return bool(np.all(close))


def _stated_value(fact: str, stated: Mapping, n_bodies: int, source: Path):
    key = KEYS[fact][0]
    value = stated.get(key)
    if value is None:
        return None
    if fact == "depth":
        return math.inf if value == "inf" else float(value)
    if fact in ("xbody", "vcg", "volume"):
        if len(value) != n_bodies:
            raise HDBError(source, f"wamit.{key}", f"{len(value)} values for the run's {n_bodies} bodies "
                                                   "(one per body, in the run's order)")
        return [list(v)[:3] + [0.0] if fact == "xbody" else v for v in value]
    return value


def run_facts(stem: Path, file1: Path, first_column: np.ndarray, max_mode: int,
              stated: Mapping | None) -> RunFacts:
    """The run's facts (module docstring); ``first_column``: the ``.1``'s first column;
    ``max_mode``: the highest mode index it holds."""
    stated = dict(stated or {})
    cfg = read_cfg(stem)
    found, n_bodies = _file_facts(stem, file1, max_mode, cfg, stated)
    values: dict[str, object] = {}
    origin: dict[str, str] = {}
    for fact in ("g", "ulen", "depth", "xbody", "vcg", "volume"):
        given = _stated_value(fact, stated, n_bodies, file1)
        if fact in found:
            value, where = found[fact]
            if given is not None and not _agree(np.asarray(value, float)[..., :3] if fact == "xbody" else value,
                                                np.asarray(given, float)[..., :3] if fact == "xbody" else given):
                raise HDBError(where, KEYS[fact][1], f"the file states {value}, the scene's wamit.{KEYS[fact][0]} "
                                                     f"{given}: remove the key or correct it")
            values[fact], origin[fact] = value, where
        elif given is not None:
            values[fact], origin[fact] = given, f"the scene's wamit.{KEYS[fact][0]}"
    values["iperout"], origin["iperout"] = _iperout(found, first_column, stated, values, file1, cfg)
    vcg = values.get("vcg")
    needed = ("volume",) if vcg is not None and np.any(np.asarray(vcg, float) != 0.0) else ()   # for the .hst
    missing = [f for f in ("ulen", "g", "depth", "xbody", "vcg", "iperout", *needed) if values.get(f) is None]
    if missing:
        raise _missing_error(stem, file1, missing)
    return _assemble(values, origin, found, n_bodies)


def _missing_error(stem: Path, file1: Path, missing: list[str]) -> HDBError:
    read = [s for s in (".out", ".mmx", ".pot", ".frc", ".cfg") if _sibling(stem, s).is_file()]
    absent = [s for s in (".out", ".mmx", ".pot", ".frc", ".cfg") if s not in read]
    what = ", ".join(KEYS[f][1] for f in missing)
    keys = ", ".join(KEYS[f][0] for f in missing)
    files = (f"{', '.join(stem.name + s for s in read)} beside it" if read else "no file beside it") + \
        (f" (no {'/'.join(absent)})" if absent else "")
    why = (f"the run's {what} {'is' if len(missing) == 1 else 'are'} stated by no file: {files}; state "
           f"{'it' if len(missing) == 1 else 'them'} in the body's [bodies.wamit] table ({keys})")
    if "iperout" in missing:
        why += " (iperout: 1 if the first column holds periods in s, 2 angular frequencies, 3 ω²L/g)"
    if "volume" in missing:
        why += " (volume: each body's displaced volume in m^3, needed to take the .hst's -m g VCG terms out)"
    return HDBError(file1, f"wamit.{KEYS[missing[0]][0]}" if len(missing) == 1 else "wamit", why)


def _iperout(found: dict, first_column: np.ndarray, stated: Mapping, values: dict, file1: Path,
             cfg: dict) -> tuple[int | None, str]:
    """IPEROUT from the .cfg, else from the .out's period list, else stated; cross-checked."""
    from_out = None
    if "out_periods" in found and values.get("g") is not None and values.get("ulen") is not None:
        from_out = _iperout_from_periods(found["out_periods"], first_column, values, file1)
    given = stated.get("iperout")
    chosen, where = None, ""
    if "iperout" in found:
        chosen, where = found["iperout"]
        if chosen not in IPEROUT_MEANING:
            raise HDBError(where, "IPEROUT", f"output frequency type {chosen} is not supported (1, 2 or 3)")
        if from_out is not None and from_out != chosen:
            raise HDBError(where, "IPEROUT", f"{chosen} ({IPEROUT_MEANING[chosen]}), but {file1.name}'s first column "
                                             f"matches {found['out_periods'][1]}'s period list as "
                                             f"{IPEROUT_MEANING[from_out]} (IPEROUT {from_out})")
    elif from_out is not None:
        chosen, where = from_out, f"{found['out_periods'][1]}'s period list"
    if given is not None:
        if chosen is not None and given != chosen:
            raise HDBError(where, "IPEROUT", f"{IPEROUT_MEANING[chosen]} (IPEROUT {chosen}), the scene's "
                                             f"wamit.iperout {given}: remove the key or correct it")
        if chosen is None:
            chosen, where = int(given), "the scene's wamit.iperout"
    return chosen, where


def frequency_of(values: np.ndarray, iperout: int, g: float, ulen: float) -> np.ndarray:
    """Angular frequency of positive first-column values."""
    if iperout == 1:
        return 2.0 * np.pi / values
    if iperout == 2:
        return np.asarray(values, float)
    return np.sqrt(g * np.asarray(values, float) / ulen)


def _iperout_from_periods(out_periods: tuple, first_column: np.ndarray, values: dict, file1: Path) -> int | None:
    """The IPEROUT under which the .1's first column is the .out's period list (None: ambiguous)."""
    listed, where = out_periods
    periods = np.array([p for p, _ in listed if p > 0])
    half_ulp = np.array([h for p, h in listed if p > 0])
    column = np.unique(first_column[first_column > 0])
    if periods.size == 0:
        return None
    order = np.argsort(periods)
    omega_out = 2 * np.pi / periods[order]
    tol = omega_out * (1.2 * half_ulp[order] / periods[order] + 1e-6)
    matches = []
    for iperout in IPEROUT_MEANING:
        omega = np.sort(frequency_of(column, iperout, float(values["g"]), float(values["ulen"])))[::-1]
        if omega.size == omega_out.size and np.all(np.abs(omega - omega_out) <= tol):
            matches.append(iperout)
    if not matches:
        raise HDBError(where, "Period", f"{file1.name}'s first column ({column.size} values) is the period list "
                                        f"here ({periods.size} periods) neither as periods, angular frequencies "
                                        "nor ω²L/g (IPEROUT 1, 2, 3): is this report of the same run?")
    return matches[0] if len(matches) == 1 else None


def _assemble(values: dict, origin: dict, found: dict, n_bodies: int) -> RunFacts:
    xbody = np.asarray(values["xbody"], float).reshape(n_bodies, -1)
    if xbody.shape[1] >= 4 and np.any(xbody[:, 3] != 0.0):
        raise HDBError(origin["xbody"], "PHIBODY",
                       "bodies rotated about z (PHIBODY != 0) are not supported: their coefficients are in body axes")
    vcg = np.asarray(values["vcg"], float)
    ialtfrc, ialtfrc_from = found.get("ialtfrc", (1, ""))
    if ialtfrc != 1 and np.any(vcg != 0):
        raise HDBError(ialtfrc_from, "IALTFRC", f"{ialtfrc} with VCG {vcg.tolist()}: the .hst's gravity terms then "
                                                "use the .frc's mass, which is not read; only IALTFRC = 1 (mass = rho "
                                                "V) is supported with VCG != 0")
    volume = None if values.get("volume") is None else np.asarray(values["volume"], float)
    cb = None
    if "cb" in found:
        cb = xbody[:, :3] + np.asarray(found["cb"][0], float)
    names_found = found.get("names")
    names = _body_names(names_found[0] if names_found else [], n_bodies)
    if names_found:
        origin["names"] = names_found[1]
    modes = found["modes"][0]
    if any(modes) and float(values["ulen"]) != 1.0:
        warnings.warn(f"{origin['ulen']}: ULEN = {values['ulen']} with generalized modes: their columns are read "
                      "scaled like translations' (the modes' own scaling is the run's): check them or rerun with "
                      "ULEN = 1", HDBWarning, stacklevel=5)
    return RunFacts(float(values["g"]), float(values["ulen"]), float(values["depth"]), int(values["iperout"]),
                    xbody[:, :3], vcg, volume, cb, names, origin, modes)


def _body_names(gdf: list[str], n_bodies: int) -> list[str]:
    """Body names from the ``.gdf`` stems (dots replaced, made unique) or body1, body2..."""
    if len(gdf) != n_bodies:
        return [f"body{n + 1}" for n in range(n_bodies)]
    names = [g.replace(".", "_") or f"body{n + 1}" for n, g in enumerate(gdf)]
    if len(set(names)) != len(names):
        names = [f"{name}{n + 1}" for n, name in enumerate(names)]
    return names
