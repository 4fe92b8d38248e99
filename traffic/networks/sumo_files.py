"""``sumo_files``: a user's own SUMO network and demand (a ``.net.xml`` from ``netconvert`` or
``netgenerate``, e.g. built from OpenStreetMap, its route and additional files, or a ``.sumocfg``
that names them), used as they are.

The files are named relative to the scenario file and must exist at load.  The build copies them into
the network cache (so a batch never reads a file the user is editing; an edited file, seen by its
size and modification time, is a new cache entry).  The ``file`` attribute of every element of an
additional file (detector and edge-data outputs) is set to ``NUL`` (SUMO's "write nothing"): SUMO
writes files only where corridor says, inside the batch folder (``road.sumo.outputs``).  The named
``<route>`` elements of the route and additional files become the network's routes (corridor flows
may use them); the landmarks are what is measured on the network (``SumoFilesLandmarks``): no merge,
ramp or bay, so the controllers that need those refuse such a network at load.
"""

from __future__ import annotations

import gzip
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import sumolib
from pydantic import BaseModel, ConfigDict, field_validator, model_validator

from corridor.errors import clip
from corridor.scenario import ScenarioFile, resolving_files
from corridor.traffic.networks.landmarks import SumoFilesLandmarks
from corridor.traffic.networks.registry import NET_FILE, BuildOutput, NetworkBuildError, register_builder

NULL_OUTPUT = "NUL"  # SUMO's name for "discard this output"
ROOTS = {"net": ("net",), "routes": ("routes",), "additional": ("additional", "add", "routes")}


class SumoFilesParams(BaseModel):
    """Either ``net`` (with optional ``routes`` and ``additional``) or ``sumocfg`` (whose ``<input>``
    names them; ``routes`` and ``additional`` given here are loaded after the config's)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    net: ScenarioFile | None = None  # a SUMO network (.net.xml or .net.xml.gz)
    routes: list[ScenarioFile] = []  # SUMO route files: vTypes, routes, vehicles, flows, trips
    additional: list[ScenarioFile] = []  # SUMO additional files (stops, TLS programs, detectors, ...)
    sumocfg: ScenarioFile | None = None  # a SUMO config: only its input files are used

    @field_validator("routes", "additional", mode="before")
    @classmethod
    def _one_or_many(cls, value: Any) -> Any:
        return [value] if isinstance(value, str) else value

    @model_validator(mode="after")
    def _one_source(self) -> SumoFilesParams:
        if (self.net is None) == (self.sumocfg is None):
            raise ValueError("give exactly one of net (a .net.xml) or sumocfg (a .sumocfg)")
        if not resolving_files():
            return self  # validated without the scenario's folder (a report): not read here
        net, routes, additional = self.resolved()
        for kind, files in (("net", [net]), ("routes", routes), ("additional", additional)):
            for f in files:
                _check_root(f, kind)
        return self

    def resolved(self) -> tuple[Path, list[Path], list[Path]]:
        """(net, route files, additional files) as absolute paths, the config's first."""
        routes, additional = [Path(r) for r in self.routes], [Path(a) for a in self.additional]
        if self.sumocfg is None:
            return Path(str(self.net)), routes, additional
        net, cfg_routes, cfg_additional = read_sumocfg(Path(self.sumocfg))
        return net, cfg_routes + routes, cfg_additional + additional

    def input_files(self) -> list[Path]:
        """Every file the network is built from (their versions are part of the cache key)."""
        net, routes, additional = self.resolved()
        return [*([Path(self.sumocfg)] if self.sumocfg else []), net, *routes, *additional]


def read_sumocfg(path: Path) -> tuple[Path, list[Path], list[Path]]:
    """The net, route and additional files a ``.sumocfg`` names (relative to its folder); each must
    exist.  Its other options (time, processing, outputs) are not used: the scenario sets those."""
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ValueError(f"sumocfg {clip(path.name)}: not a readable XML file ({exc})") from None

    def files(option: str) -> list[Path]:
        out: list[Path] = []
        for el in root.iter(option):
            for name in el.get("value", "").replace(",", " ").split():
                f = Path(name).expanduser()
                f = f if f.is_absolute() else path.parent / f
                if not f.is_file():
                    raise ValueError(f"sumocfg {clip(path.name)}: {option} {clip(name)}: no such file "
                                     f"(relative to {clip(str(path.parent), 80)[1:-1]})")
                out.append(f.resolve())
        return out

    nets = files("net-file")
    if len(nets) != 1:
        raise ValueError(f"sumocfg {clip(path.name)}: needs exactly one <net-file value=...>, found {len(nets)}")
    return nets[0], files("route-files"), files("additional-files")


def _open(path: Path) -> Any:
    return gzip.open(path, "rb") if path.suffix == ".gz" else open(path, "rb")


def _check_root(path: Path, kind: str) -> None:
    """Refuse a file whose root element is not what SUMO expects of a ``kind`` file (one line)."""
    try:
        with _open(path) as fh:
            _, first = next(ET.iterparse(fh, events=("start",)))
    except (ET.ParseError, OSError, StopIteration, EOFError) as exc:
        raise ValueError(f"{kind} {clip(path.name)}: not a readable SUMO XML file ({str(exc)[:80]})") from None
    if first.tag not in ROOTS[kind]:
        raise ValueError(f"{kind} {clip(path.name)}: root element <{clip(first.tag, 30)[1:-1]}>, a SUMO {kind} "
                         f"file has <{ROOTS[kind][0]}>")


def _copy(src: Path, dst: Path) -> Path:
    """Copy ``src`` to ``dst`` (uncompressed)."""
    with _open(src) as fin, open(dst, "wb") as fout:
        shutil.copyfileobj(fin, fout)
    return dst


def _copy_additional(src: Path, dst: Path) -> Path:
    """Copy an additional file with every ``file`` attribute (an output of a detector, edge data,
    ...) set to ``NUL``: SUMO writes nowhere but the batch folder."""
    with _open(src) as fh:
        tree = ET.parse(fh)
    for el in tree.getroot().iter():
        if "file" in el.attrib:
            el.set("file", NULL_OUTPUT)
    tree.write(dst, encoding="UTF-8", xml_declaration=True)
    return dst


def _named_routes(files: list[Path]) -> dict[str, tuple[str, ...]]:
    """The top-level ``<route id=... edges=...>`` elements of route/additional files."""
    routes: dict[str, tuple[str, ...]] = {}
    for f in files:
        with _open(f) as fh:
            root = ET.parse(fh).getroot()
        for el in root.findall("route"):
            if el.get("id") and el.get("edges"):
                routes[el.get("id", "")] = tuple(el.get("edges", "").split())
    return routes


def measure(net_file: Path) -> SumoFilesLandmarks:
    """What corridor knows of a user's network: counts, lane length, lane width, extent."""
    net = sumolib.net.readNet(str(net_file))
    lanes = [lane for e in net.getEdges() for lane in e.getLanes()]
    if not lanes:
        raise NetworkBuildError(f"{net_file.name}: the network has no lanes")
    xmin, ymin, xmax, ymax = net.getBoundary()
    return SumoFilesLandmarks(
        lane_width_m=float(sum(lane.getWidth() for lane in lanes) / len(lanes)), edges=len(net.getEdges()),
        lanes=len(lanes), lanes_length_m=float(sum(lane.getLength() for lane in lanes)),
        bbox_m=(float(xmin), float(ymin), float(xmax), float(ymax)))


@register_builder("sumo_files", SumoFilesParams, SumoFilesLandmarks)
def build_sumo_files(params: SumoFilesParams, work_dir: Path) -> BuildOutput:
    """Copy the user's files into ``work_dir`` (the cache entry being built) and measure the network."""
    net, routes, additional = params.resolved()
    _copy(net, work_dir / NET_FILE)
    route_files = [_copy(r, work_dir / f"routes{k}-{_plain(r)}") for k, r in enumerate(routes)]
    add_files = [_copy_additional(a, work_dir / f"additional{k}-{_plain(a)}") for k, a in enumerate(additional)]
    return BuildOutput(additional_files=tuple(f.name for f in add_files),
                       routes=_named_routes([*add_files, *route_files]),
                       landmarks=measure(work_dir / NET_FILE),
                       route_files=tuple(f.name for f in route_files), user_files=True)


def _plain(path: Path) -> str:
    """The file's name without a ``.gz`` (the copy is uncompressed)."""
    return path.stem if path.suffix == ".gz" else path.name
