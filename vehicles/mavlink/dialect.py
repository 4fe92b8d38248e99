"""corridor's MAVLink 2 dialect (``dialects/corridor_traffic.xml``: ``common.xml`` + TRAFFIC_SEGMENT_ESTIMATE),
generated into Python by pymavlink's own generator (``pymavlink.generator.mavgen``) on first use.

The generated module is not committed: :func:`dialect` writes it into a cache folder
(``$CORRIDOR_CACHE/mavlink`` or ``~/.cache/corridor/mavlink``), named by a hash of the XML and of
pymavlink's version, so a changed XML or a new pymavlink regenerates it. ``common.xml`` and the
files it includes are taken from pymavlink's own ``dialects/v20`` folder (the XML includes them by
name). Generation is atomic (a temporary file renamed into place), so parallel worker processes
may race safely. ``python -m corridor.vehicles.mavlink.dialect`` generates it ahead of time (a build
step) and prints the path.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import io
import os
import shutil
import sys
import tempfile
from functools import cache
from pathlib import Path
from types import ModuleType

XML = Path(__file__).resolve().parent / "dialects" / "corridor_traffic.xml"
NAME = "corridor_traffic"
TRAFFIC_SEGMENT_ESTIMATE = "TRAFFIC_SEGMENT_ESTIMATE"


def cache_dir() -> Path:
    root = os.environ.get("CORRIDOR_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "corridor") / "mavlink"


def _pymavlink_v20() -> Path:
    import pymavlink

    return Path(pymavlink.__file__).resolve().parent / "dialects" / "v20"


def _key() -> str:
    import pymavlink

    version = getattr(pymavlink, "__version__", "") or str(_pymavlink_v20())
    return hashlib.blake2b(XML.read_bytes() + version.encode(), digest_size=8).hexdigest()


def generate(out_py: Path) -> Path:
    """Run mavgen on the dialect XML (with pymavlink's ``common.xml`` beside it) -> ``out_py``."""
    from pymavlink.generator import mavgen

    out_py.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out_py.parent) as tmp:
        src = Path(tmp)
        for name in ("common.xml", "standard.xml", "minimal.xml"):
            shutil.copy2(_pymavlink_v20() / name, src / name)
        shutil.copy2(XML, src / XML.name)
        target = src / f"{NAME}.py"
        opts = mavgen.Opts(str(target), wire_protocol="2.0", language="Python3", validate=False)
        with contextlib.redirect_stdout(io.StringIO()):  # mavgen reports every step on stdout
            mavgen.mavgen(opts, [str(src / XML.name)])
        os.replace(target, out_py)
    return out_py


@cache
def dialect() -> ModuleType:
    """The generated dialect module (generated on first use, then loaded from the cache)."""
    path = cache_dir() / f"{NAME}_{_key()}.py"
    if not path.is_file():
        generate(path)
    spec = importlib.util.spec_from_file_location(f"corridor_mavlink_{NAME}", path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load the generated MAVLink dialect {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


if __name__ == "__main__":
    mod = dialect()
    print(mod.__file__)
