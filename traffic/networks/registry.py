"""SUMO network builders: registry, content-addressed cache and the netconvert call.

A builder turns a frozen pydantic params model into plain-XML nodes/edges/connections (plus traffic
light programs and detector definitions), runs ``netconvert`` from the eclipse-sumo wheel, and reports
routes and typed landmarks (``corridor.traffic.networks.landmarks``).  ``build_network`` caches the result under a hash of (builder name,
params, SUMO version, builder source) so that the many processes of a Monte Carlo batch build each
network once; entries are written into a temporary directory and renamed into place, which is atomic
on one file system, so concurrent builders never see half-written files.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
import sumolib
from pydantic import BaseModel

from corridor.entrypoints import Registry
from corridor.traffic.networks.landmarks import Landmarks, parse_landmarks

CACHE_FORMAT = 2  # bump when the on-disk layout or any builder's output changes
META_FILE = "meta.json"
NET_FILE = "network.net.xml"


class NetworkBuildError(RuntimeError):
    """netconvert (or a builder) failed; the message is one readable line."""


@dataclass(frozen=True, eq=False)
class BuiltNetwork:
    """A built SUMO network and the facts controllers and monitors need about it."""

    net_file: Path
    additional_files: tuple[Path, ...]  # detectors, TLS programs (may be empty)
    routes: Mapping[str, tuple[str, ...]]  # route name -> edge ids
    landmarks: Landmarks  # typed, frozen facts of the builder (merge point, lanes, detectors, ...)
    params_hash: str
    route_files: tuple[Path, ...] = ()  # a user's own SUMO route files (their vehicles, types, routes)
    user_files: bool = False  # the network's own files declare its routes and vehicles (a user's network)

    @cached_property
    def lane_shapes(self) -> Mapping[str, np.ndarray]:
        """Lane id -> (n, 2) polyline, SUMO x/y [m]; read on first use (the Rerun recorder): sumolib
        parses a city-sized network file for tens of seconds, which a run without it never pays."""
        return read_lane_shapes(self.net_file)


@dataclass(frozen=True)
class BuildOutput:
    """What a build function returns: file names relative to its work dir, routes, landmarks."""

    additional_files: tuple[str, ...]
    routes: Mapping[str, Sequence[str]]
    landmarks: Landmarks
    route_files: tuple[str, ...] = ()  # SUMO route files in the work dir, loaded as they are
    user_files: bool = False  # the routes are declared by those (or the additional) files


@dataclass
class PlainNet:
    """SUMO plain-XML network description: one attribute dict per element."""

    nodes: list[dict[str, Any]] = field(default_factory=list)
    edges: list[dict[str, Any]] = field(default_factory=list)
    connections: list[dict[str, Any]] = field(default_factory=list)
    tl_logics: list[tuple[dict[str, Any], list[dict[str, Any]]]] = field(default_factory=list)


BuildFn = Callable[[Any, Path], BuildOutput]
BUILDERS: dict[str, tuple[type[BaseModel], BuildFn]] = {}
LANDMARKS: dict[str, type[Landmarks]] = {}  # builder name -> the landmarks model its networks carry
# every builder, corridor's own and a plug-in's, is an entry point of this group: ``name = "pkg.module"``,
# a module that registers ``name`` with ``register_builder`` when imported (only when a scenario uses it)
# (the kernel's entry-point mechanism: one name declared twice differently is an error)
ENTRY_POINTS = "corridor.networks"
NETWORKS = Registry("network kind", ENTRY_POINTS)


def register_builder(name: str, model: type[BaseModel],
                     landmarks: type[Landmarks] = Landmarks) -> Callable[[BuildFn], BuildFn]:
    """Decorator: register ``fn(params, work_dir) -> BuildOutput`` under ``name``; ``landmarks`` is
    the model of the landmarks it reports (checked at load by the components that need some)."""

    def decorate(fn: BuildFn) -> BuildFn:
        BUILDERS[name] = (model, fn)
        LANDMARKS[name] = landmarks
        return fn

    return decorate


def params_model(kind: str) -> type[BaseModel]:
    """The params model of builder ``kind`` (for the scenario loader to validate ``network.params``)."""
    return _lookup(kind)[0]


def landmarks_model(kind: str) -> type[Landmarks]:
    """The landmarks model of the networks of builder ``kind`` (known without building one)."""
    _lookup(kind)
    return LANDMARKS.get(kind, Landmarks)


def builder_names() -> list[str]:
    """Every builder name: the ``corridor.networks`` entry points and those registered in code."""
    return sorted(set(NETWORKS) | set(BUILDERS))


def _lookup(kind: str) -> tuple[type[BaseModel], BuildFn]:
    """The builder ``kind``: its module imported on first use (an ``UnknownName``, a KeyError, if none)."""
    if kind not in BUILDERS and kind in NETWORKS:
        NETWORKS.get(kind)  # imports the module, which registers the builder
    if kind not in BUILDERS:
        raise NETWORKS.unknown(kind, builder_names())
    return BUILDERS[kind]


# ---------------------------------------------------------------------------------------------------
# XML writing and netconvert


def fmt(value: Any) -> str:
    """Format an attribute value: floats to the millimetre, shapes as 'x,y x,y'."""
    if isinstance(value, float):
        return f"{value:.3f}"
    if isinstance(value, (list, tuple)) and value and isinstance(value[0], (list, tuple, np.ndarray)):
        return " ".join(f"{fmt(float(x))},{fmt(float(y))}" for x, y in value)
    return str(value)


def element(tag: str, attrs: Mapping[str, Any], children: Sequence[str] = ()) -> str:
    """One XML element with quoted attributes (children are pre-rendered strings)."""
    body = " ".join(f"{k}={quoteattr(fmt(v))}" for k, v in attrs.items())
    if not children:
        return f"<{tag} {body}/>"
    inner = "\n".join(f"    {c}" for c in children)
    return f"<{tag} {body}>\n{inner}\n</{tag}>"


def write_xml(path: Path, root: str, elements: Sequence[str]) -> Path:
    """Write ``<root>`` with the given pre-rendered child elements."""
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f"<{root}>",
        *(f"    {e}" for e in elements),
        f"</{root}>",
    ]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def netconvert_binary() -> Path:
    """The netconvert of the installed eclipse-sumo wheel (falls back to PATH)."""
    import sumo  # the eclipse-sumo wheel; imported here so this module loads without it

    candidate = Path(sumo.SUMO_HOME) / "bin" / "netconvert"
    if candidate.exists():
        return candidate
    found = shutil.which("netconvert")
    if found is None:
        raise NetworkBuildError("netconvert not found (eclipse-sumo wheel not installed?)")
    return Path(found)


def sumo_version() -> str:
    """Version of the eclipse-sumo wheel (part of the cache key)."""
    return importlib.metadata.version("eclipse-sumo")


def run_netconvert(work_dir: Path, plain: PlainNet, extra_args: Sequence[str] = ()) -> Path:
    """Write the plain XML files into ``work_dir`` and run netconvert; returns the .net.xml path."""
    args = [
        "--node-files",
        str(write_xml(work_dir / "plain.nod.xml", "nodes", [element("node", n) for n in plain.nodes])),
        "--edge-files",
        str(write_xml(work_dir / "plain.edg.xml", "edges", [element("edge", e) for e in plain.edges])),
    ]
    if plain.connections:
        con = write_xml(
            work_dir / "plain.con.xml", "connections", [element("connection", c) for c in plain.connections]
        )
        args += ["--connection-files", str(con)]
    if plain.tl_logics:
        logics = [element("tlLogic", a, [element("phase", p) for p in ph]) for a, ph in plain.tl_logics]
        args += ["--tllogic-files", str(write_xml(work_dir / "plain.tll.xml", "tlLogics", logics))]
    net_file = work_dir / NET_FILE
    cmd = [
        str(netconvert_binary()),
        *args,
        "--output-file",
        str(net_file),
        "--no-turnarounds",
        "true",
        "--offset.disable-normalization",
        "true",
        "--no-warnings",
        "true",
        *extra_args,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0 or not net_file.exists():
        raise NetworkBuildError(f"netconvert failed: {_first_error_line(proc.stderr + proc.stdout)}")
    return net_file


def _first_error_line(output: str) -> str:
    """netconvert's first 'Error:' line (or its last non-empty line), stripped to one line."""
    lines = [ln.strip() for ln in output.splitlines() if ln.strip()]
    for line in lines:
        if line.startswith("Error:"):
            return line
    return lines[-1] if lines else "no output"


def read_lane_shapes(net_file: Path) -> dict[str, np.ndarray]:
    """Lane id -> (n, 2) centre polyline [m] for all lanes, internal (junction) lanes included."""
    net = sumolib.net.readNet(str(net_file), withInternal=True)
    shapes: dict[str, np.ndarray] = {}
    for edge in net.getEdges(withInternal=True):
        for lane in edge.getLanes():
            shapes[lane.getID()] = np.asarray(lane.getShape(), dtype=float)[:, :2]
    return shapes


# ---------------------------------------------------------------------------------------------------
# Cache


def default_cache_dir() -> Path:
    """``$CORRIDOR_CACHE`` if set, else ``~/.cache/corridor/networks``."""
    env = os.environ.get("CORRIDOR_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "corridor" / "networks"


def params_hash(kind: str, params: BaseModel) -> str:
    """Stable hash of (builder name, params, SUMO version, cache format, builder source code).

    The source of the builder module and of this module are part of the key, so editing a builder
    never serves a stale network from the cache.
    """
    key = {
        "kind": kind,
        "params": params.model_dump(mode="json"),
        "sumo": sumo_version(),
        "format": CACHE_FORMAT,
        "code": _code_digest(kind),
    }
    files = getattr(params, "input_files", None)  # a builder reading a user's files: their versions
    if files is not None:
        key["files"] = [_file_stamp(Path(f)) for f in files()]
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]


def _file_stamp(path: Path) -> list[Any]:
    """(path, size [B], modification time [ns]) of an input file: an edited file is a new entry."""
    st = path.stat()
    return [str(path), st.st_size, st.st_mtime_ns]


def _code_digest(kind: str) -> str:
    """sha256 of the builder's module file and this file."""
    digest = hashlib.sha256()
    for module_name in (_lookup(kind)[1].__module__, __name__):
        source = getattr(sys.modules.get(module_name), "__file__", None)
        if source:
            digest.update(Path(source).read_bytes())
    return digest.hexdigest()[:16]


def build_network(
    kind: str, params: Mapping[str, Any] | BaseModel, cache_dir: Path | None = None
) -> BuiltNetwork:
    """Build (or load from the cache) the network ``kind`` with ``params``."""
    model, build_fn = _lookup(kind)
    p = params if isinstance(params, model) else model.model_validate(dict(params))  # type: ignore[arg-type]
    digest = params_hash(kind, p)
    root = (cache_dir or default_cache_dir()).expanduser()
    entry = root / f"{kind}-{digest}"
    if not (entry / META_FILE).exists():
        _build_into_cache(kind, p, build_fn, entry, digest)
    return _load_entry(entry, digest)


def _build_into_cache(kind: str, params: BaseModel, build_fn: BuildFn, entry: Path, digest: str) -> None:
    """Build in a private temp dir beside ``entry`` and rename it into place (atomic publish)."""
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{entry.name}.", dir=entry.parent))
    try:
        out = build_fn(params, tmp)
        meta = {
            "kind": kind,
            "params_hash": digest,
            "params": params.model_dump(mode="json"),
            "additional_files": list(out.additional_files),
            "routes": {k: list(v) for k, v in out.routes.items()},
            "landmarks": out.landmarks.model_dump(mode="json"),
            "route_files": list(out.route_files),
            "user_files": out.user_files,
        }
        (tmp / META_FILE).write_text(json.dumps(meta, indent=1, sort_keys=True), encoding="utf-8")
        try:
            os.rename(tmp, entry)
        except OSError:
            if not (entry / META_FILE).exists():  # not a lost race: a real failure
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _load_entry(entry: Path, digest: str) -> BuiltNetwork:
    """Read a published cache entry."""
    meta = json.loads((entry / META_FILE).read_text(encoding="utf-8"))
    net_file = entry / NET_FILE
    return BuiltNetwork(
        net_file=net_file,
        additional_files=tuple(entry / name for name in meta["additional_files"]),
        routes={k: tuple(v) for k, v in meta["routes"].items()},
        landmarks=_landmarks(meta),
        params_hash=digest,
        route_files=tuple(entry / name for name in meta.get("route_files", ())),
        user_files=bool(meta.get("user_files", False)),
    )


def _landmarks(meta: Mapping[str, Any]) -> Landmarks:
    """The typed landmarks of a cache entry (the model its builder registered, else by their kind)."""
    model = LANDMARKS.get(meta["kind"])
    if model is not None and model is not Landmarks:
        return model.model_validate(meta["landmarks"])
    return parse_landmarks(meta["landmarks"])

