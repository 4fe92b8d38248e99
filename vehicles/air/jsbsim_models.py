"""JSBSim aircraft directories with corridor's FCS systems added (package data ``jsbsim_data/``).

JSBSim resolves an aircraft's ``<system file="...">`` in the aircraft's own directory (then its
``Systems`` folder, then the root's ``systems``); the F450 shipped in the jsbsim wheel lists no
corridor system. :func:`aircraft_dir` therefore assembles, once per machine and content, a
private aircraft directory in corridor's cache: a copy of the wheel's ``aircraft/F450`` whose
``F450.xml`` gains one line, ``<system file="corridor_quad_cascade"/>``, next to corridor's system
file. JSBSim loads every ``<system>`` before the ``<flight_control>`` into one FCS and runs the
channels in that order, so the cascade's stick outputs feed the F450's own rate loops in the same
sub-step. The folder is named by a hash of everything it is made from (the wheel's files, corridor's
system files and this module), published atomically (built beside it, then renamed) and reused by
every process: a batch's forked runners, which skip ``atexit``, leave no folder behind (one temp folder
per worker did before).  ``$CORRIDOR_CACHE/jsbsim`` if set, else ``~/.cache/corridor/jsbsim``; a
cache that cannot be written falls back to a temporary folder removed at exit.  Nothing is written
into the wheel.

The copy leaves out the F450's GPS and barometer sensor systems (``SensorGps.xml``,
``SensorBaro.xml``) and keeps of its IMU (``SensorImu.xml``) only the yaw-rate gyro: the F450's FCS
reads ``sensor/imu/gyroZ_rps`` and no other sensor output, corridor reads the true state, and each
sensor draws its noise from its own generator. The gyro is taken from the wheel's own file at run
time (``_reduced_imu``), not copied into corridor. Together they cost ~25 % of a sub-step; a test
checks that the flight is bit-identical with the full sensor set.
"""

from __future__ import annotations

import atexit
import functools
import hashlib
import os
import shutil
import tempfile
from importlib import resources
from pathlib import Path
from xml.etree import ElementTree

CASCADE_SYSTEM = "corridor_quad_cascade"  # file stem in jsbsim_data/ and the <system file=...> name
_PATCHED = {"F450": CASCADE_SYSTEM}  # aircraft -> corridor system added to it
UNUSED_SYSTEMS = ("SensorBaro", "SensorGps")  # systems left out of the copy (outputs nobody reads)
REDUCED_IMU = "corridor_imu_gyro_z"  # the IMU system cut down to the sensor the FCS reads


def system_xml(name: str) -> str:
    """Text of one of corridor's JSBSim system files (package data)."""
    return resources.files("corridor.vehicles.air").joinpath("jsbsim_data", f"{name}.xml").read_text()


@functools.lru_cache(maxsize=4)
def aircraft_dir(root: str, omit: tuple[str, ...] = UNUSED_SYSTEMS, reduce_imu: bool = True) -> str:
    """Aircraft path holding the patched copies of ``_PATCHED`` for the JSBSim data dir ``root``,
    without the ``<system file=...>`` entries named in ``omit`` and (``reduce_imu``) with the IMU
    cut down to its yaw-rate gyro."""
    key = _content_key(root, omit, reduce_imu)
    entry = cache_dir() / f"aircraft-{key}"
    if (entry / DONE).exists():
        return str(entry)
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{entry.name}.", dir=entry.parent))
    except OSError:  # no writable cache: a private folder for this process
        out = Path(tempfile.mkdtemp(prefix="corridor-jsbsim-"))
        atexit.register(shutil.rmtree, out, True)
        _assemble(out, root, omit, reduce_imu)
        return str(out)
    try:
        _assemble(tmp, root, omit, reduce_imu)
        (tmp / DONE).write_text(key)
        try:
            os.rename(tmp, entry)
        except OSError:
            if not (entry / DONE).exists():  # not a lost race with another process: a real failure
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return str(entry)


DONE = ".complete"  # written last: a folder without it is unfinished


def cache_dir() -> Path:
    """``$CORRIDOR_CACHE/jsbsim`` if set, else ``~/.cache/corridor/jsbsim``."""
    env = os.environ.get("CORRIDOR_CACHE")
    return (Path(env) if env else Path("~/.cache/corridor")).expanduser() / "jsbsim"


def _content_key(root: str, omit: tuple[str, ...], reduce_imu: bool) -> str:
    """sha256 over what the folder is made of: the wheel's aircraft and IMU files, corridor's system
    files, this module's source and the options."""
    h = hashlib.sha256(repr((sorted(omit), reduce_imu, sorted(_PATCHED.items()))).encode())
    for model, system in sorted(_PATCHED.items()):
        src = Path(root) / "aircraft" / model
        for f in sorted(p for p in src.rglob("*") if p.is_file()):
            h.update(str(f.relative_to(src)).encode() + b"\0" + f.read_bytes())
        h.update(system_xml(system).encode())
    imu = Path(root) / "systems" / "SensorImu.xml"
    if imu.is_file():
        h.update(imu.read_bytes())
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()[:20]


def _assemble(out: Path, root: str, omit: tuple[str, ...], reduce_imu: bool) -> None:
    for model, system in _PATCHED.items():
        dst = out / model
        shutil.copytree(Path(root) / "aircraft" / model, dst)
        main = dst / f"{model}.xml"
        text = main.read_text()
        if "</fdm_config>" not in text:
            raise RuntimeError(f"unexpected JSBSim aircraft file {main}: no </fdm_config>")
        for name in omit:
            line = f'<system file="{name}.xml"/>'
            if line not in text:
                raise RuntimeError(f"{main}: no {line} to leave out")
            text = text.replace(line, f"<!-- {name} left out by corridor (outputs unused) -->", 1)
        imu = '<system file="SensorImu.xml"/>'
        if reduce_imu and imu in text:
            (dst / f"{REDUCED_IMU}.xml").write_text(_reduced_imu(Path(root) / "systems" / "SensorImu.xml"))
            text = text.replace(imu, f'<system file="{REDUCED_IMU}"/>', 1)
        main.write_text(text.replace("</fdm_config>", f'    <system file="{system}"/>\n</fdm_config>', 1))
        (dst / f"{system}.xml").write_text(system_xml(system))


def patched(model: str) -> bool:
    """True if corridor loads ``model`` from :func:`aircraft_dir` (with its own FCS system)."""
    return model in _PATCHED


def _reduced_imu(path: Path, gyro: str = "GyroZ") -> str:
    """JSBSim's IMU system file reduced to its ``gyro`` sensor (same element, same output)."""
    tree = ElementTree.parse(path)
    found = tree.getroot().find(f".//gyro[@name='{gyro}']")
    if found is None:
        raise RuntimeError(f"{path}: no <gyro name={gyro!r}>")
    system = ElementTree.Element("system", name=f"Sensor - IMU ({gyro} only, corridor)")
    ElementTree.SubElement(system, "channel", name="Gyros").append(found)
    return '<?xml version="1.0"?>\n' + ElementTree.tostring(system, encoding="unicode") + "\n"
