"""The plan's geofence drawn elsewhere: a KML polygon (Google Earth, QGIS) or a QGroundControl ``.plan``.

``[geofence] file = "area.kml"`` (or ``"area.plan"``, relative to the plan file) replaces
``polygon_enu_m`` / ``polygon_latlon_deg``: :func:`read_fence_file` reads the file into a
:class:`FenceFile` (the polygon's latitudes and longitudes, and the home the file gives, if any:
QGroundControl's ``plannedHomePosition``, or the one KML ``Point`` placemark), and
:func:`fence_in_mission_frame` converts the polygon into the mission frame about the plan's
origin through :class:`formation.geodesy.TangentFrame`.

The safety envelope (:class:`mission.safety.fence.Geofence`) is ONE simple polygon, extruded
between the plan's ``min_alt_m`` and ``max_alt_m``: an inclusion zone, no holes, no exclusion
zones, no circles. A file whose fence it cannot represent exactly is refused with the reason
(:class:`FenceFileError`), never approximated: a circle is not turned into a polygon, an
exclusion zone is not dropped, a second polygon is not ignored. Self-intersection is checked
where the envelope's own geometry lives (``mission.cli.common.load_plan_or_fail`` builds the
:class:`~mission.safety.fence.Geofence`).

KML is read with lxml (entities not resolved, no network, no DTD: an XML bomb or an external
entity is refused, never expanded); ``.plan`` with the standard :mod:`json`.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from formation.geodesy import TangentFrame

__all__ = ["FenceFile", "FenceFileError", "MAX_FENCE_FILE_BYTES", "MAX_FENCE_RADIUS_M", "MAX_FENCE_VERTICES",
           "fence_in_mission_frame", "parse_kml", "parse_qgc_plan", "read_fence_file"]

#: a fence file larger than this is refused unread (a fence of a few hundred vertices is a few kB)
MAX_FENCE_FILE_BYTES = 1_000_000
#: a fence with more vertices is refused (the envelope checks every pair of edges)
MAX_FENCE_VERTICES = 500
#: a vertex farther than this from the mission origin is refused (swapped latitude and longitude,
#: a wrong origin): the mission frame is a tangent plane, metres about a nearby origin
MAX_FENCE_RADIUS_M = 10_000.0
_KML_SUFFIXES = (".kml",)
_PLAN_SUFFIXES = (".plan", ".json")


class FenceFileError(ValueError):
    """A fence file that cannot be read, or whose fence the safety envelope cannot represent exactly."""


@dataclass(frozen=True)
class FenceFile:
    """What a fence file gives.

    Attributes
    ----------
    path : str
        The file, as named.
    what : str
        The fence it holds, in words (``KML Polygon "Search area"``, ``QGroundControl geoFence
        inclusion polygon``).
    polygon_latlon_deg : tuple of (float, float)
        The polygon's vertices ``(lat_deg, lon_deg)``, not closed.
    home : tuple of (float, float, float) or None
        ``(lat_deg, lon_deg, alt_m)`` of the home the file gives (QGroundControl's
        ``plannedHomePosition``, AMSL; a KML Point placemark, its altitude or 0), or None.
    home_problem : str or None
        Why the file's home cannot be used (several KML Point placemarks), or None.
    """

    path: str
    what: str
    polygon_latlon_deg: tuple[tuple[float, float], ...]
    home: tuple[float, float, float] | None = None
    home_problem: str | None = None


def read_fence_file(path: str | Path) -> FenceFile:
    """Read a KML (``.kml``) or QGroundControl plan (``.plan``, ``.json``) fence file.

    Raises
    ------
    FenceFileError
        Missing, unreadable, too large, of another kind, malformed, with no polygon or with a
        fence the envelope cannot represent exactly (the message says which and why).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _KML_SUFFIXES + _PLAN_SUFFIXES:
        raise FenceFileError(f"{path}: unknown fence file type {suffix or '(none)'!r}: give a .kml "
                             "(Google Earth, QGIS) or a QGroundControl .plan file")
    try:
        size = path.stat().st_size
        if size > MAX_FENCE_FILE_BYTES:
            raise FenceFileError(f"{path}: {size} bytes, more than the {MAX_FENCE_FILE_BYTES} a fence file may have")
        with open(path, "rb") as fh:
            data = fh.read(MAX_FENCE_FILE_BYTES + 1)
    except OSError as exc:
        raise FenceFileError(f"{path}: cannot read: {exc.strerror or exc}") from None
    if len(data) > MAX_FENCE_FILE_BYTES:  # it grew since stat
        raise FenceFileError(f"{path}: more than the {MAX_FENCE_FILE_BYTES} bytes a fence file may have")
    return parse_kml(data, str(path)) if suffix in _KML_SUFFIXES else parse_qgc_plan(data, str(path))


# ------------------------------------------------------------------------------------------ KML
def parse_kml(data: bytes, name: str = "KML") -> FenceFile:
    """The one Polygon of a KML document (and its one Point placemark, the home, if any).

    Raises
    ------
    FenceFileError
        Not XML, not KML, no Polygon, several Polygons, a Polygon with a hole
        (``innerBoundaryIs``), bad coordinates.
    """
    from lxml import etree

    parser = etree.XMLParser(resolve_entities=False, no_network=True, load_dtd=False, huge_tree=False)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise FenceFileError(f"{name}: not XML: {exc}") from None
    if root is None or etree.QName(root).localname != "kml":
        tag = "none" if root is None else etree.QName(root).localname
        raise FenceFileError(f"{name}: not a KML document (root element <{tag}>, expected <kml>)")
    polygons = [el for el in root.iter(etree.Element) if etree.QName(el).localname == "Polygon"]
    if not polygons:
        raise FenceFileError(f"{name}: no Polygon in the KML (draw the fence as a polygon; a path or "
                             "placemark is not a fence)")
    if len(polygons) > 1:
        raise FenceFileError(f"{name}: {len(polygons)} Polygons: the safety envelope holds one fence polygon "
                             "(keep one in the file)")
    poly = polygons[0]
    if _children(poly, "innerBoundaryIs"):
        raise FenceFileError(f"{name}: the Polygon has a hole (innerBoundaryIs): the safety envelope has no "
                             "exclusion zones")
    rings = [c for ob in _children(poly, "outerBoundaryIs") for c in _children(ob, "LinearRing")]
    coords = [c for ring in rings for c in _children(ring, "coordinates")]
    if len(coords) != 1:
        raise FenceFileError(f"{name}: the Polygon has no outerBoundaryIs/LinearRing/coordinates")
    vertices = _kml_coordinates(coords[0].text or "", name)
    points = [el for el in root.iter(etree.Element) if etree.QName(el).localname == "Point"]
    home, home_problem = None, None
    if len(points) == 1:
        home, home_problem = _kml_home(points[0], name)
    elif len(points) > 1:
        home_problem = f"{len(points)} Point placemarks in {name} (which one is home?)"
    label = _placemark_name(poly)
    what = "KML Polygon" + (f" {label!r}" if label else "")
    return FenceFile(path=name, what=what, polygon_latlon_deg=_checked_polygon(vertices, name),
                     home=home, home_problem=home_problem)


def _children(el, localname: str) -> list:
    """Direct child elements of ``el`` named ``localname`` (any namespace)."""
    from lxml import etree

    return [c for c in el if isinstance(c.tag, str) and etree.QName(c).localname == localname]


def _placemark_name(el) -> str | None:
    """The ``name`` of the Placemark holding ``el``, if any."""
    node = el.getparent()
    while node is not None:
        names = _children(node, "name")
        if names and (names[0].text or "").strip():
            return names[0].text.strip()[:60]
        node = node.getparent()
    return None


def _kml_tuples(text: str, name: str) -> list[tuple[float, ...]]:
    """KML ``lon,lat[,alt]`` tuples, whitespace separated."""
    out = []
    for j, item in enumerate(text.split()):
        parts = item.split(",")
        try:
            values = tuple(float(p) for p in parts)
        except ValueError:
            raise FenceFileError(f"{name}: coordinate {j} {item[:40]!r} is not lon,lat[,alt] numbers") from None
        if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
            raise FenceFileError(f"{name}: coordinate {j} {item[:40]!r} is not lon,lat[,alt] finite numbers")
        out.append(values)
    return out


def _kml_coordinates(text: str, name: str) -> list[tuple[float, float]]:
    """``(lat_deg, lon_deg)`` of a KML ring (KML writes longitude first)."""
    return [(v[1], v[0]) for v in _kml_tuples(text, name)]


def _kml_home(point, name: str) -> tuple[tuple[float, float, float] | None, str | None]:
    """``(home, None)`` from a KML Point with an absolute altitude, else ``(None, why not)``.

    The mission origin's altitude is AMSL: a Point clamped to the ground (KML's default
    ``altitudeMode``) or without an altitude gives none, and none is guessed.
    """
    coords = _children(point, "coordinates")
    values = _kml_tuples(coords[0].text or "", name) if coords else []
    if len(values) != 1:
        raise FenceFileError(f"{name}: a Point has {len(values)} coordinates, expected one lon,lat,alt")
    v = values[0]
    _check_lat_lon(v[1], v[0], f"{name}: the Point")
    modes = [(m.text or "").strip() for m in _children(point, "altitudeMode")]
    if len(v) != 3 or modes != ["absolute"]:
        return None, (f"the Point placemark of {name} has no absolute altitude (altitudeMode absolute and "
                      "lon,lat,alt AMSL), so it cannot be the mission origin")
    return (v[1], v[0], v[2]), None


# ------------------------------------------------------------------------------ QGroundControl
def parse_qgc_plan(data: bytes, name: str = ".plan") -> FenceFile:
    """The one inclusion polygon of a QGroundControl plan's ``geoFence`` (and its
    ``mission.plannedHomePosition``, the home).

    Raises
    ------
    FenceFileError
        Not JSON, not a QGroundControl plan, no geoFence polygon, a circle, an exclusion polygon,
        several inclusion polygons, bad coordinates.
    """
    try:
        doc = json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise FenceFileError(f"{name}: not UTF-8 text: {exc}") from None
    except ValueError as exc:
        raise FenceFileError(f"{name}: not JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("fileType") != "Plan":
        kind = doc.get("fileType") if isinstance(doc, dict) else type(doc).__name__
        raise FenceFileError(f"{name}: not a QGroundControl plan (fileType {kind!r}, expected 'Plan')")
    fence = doc.get("geoFence")
    if not isinstance(fence, dict):
        raise FenceFileError(f"{name}: no geoFence in the plan (draw the fence in QGroundControl's Fence tab)")
    circles, polygons = fence.get("circles") or [], fence.get("polygons") or []
    if "polygon" in fence:  # geoFence version 1: one inclusion polygon
        polygons = [{"polygon": fence["polygon"], "inclusion": True}]
    if not isinstance(circles, list) or not isinstance(polygons, list):
        raise FenceFileError(f"{name}: geoFence circles and polygons must be lists")
    for c in circles:
        kind = "inclusion" if isinstance(c, dict) and c.get("inclusion", True) else "exclusion"
        radius = c.get("circle", {}).get("radius") if isinstance(c, dict) and isinstance(c.get("circle"), dict) else None
        raise FenceFileError(f"{name}: a geoFence {kind} circle (radius {radius!r} m): the safety envelope holds "
                             "one polygon, not circles (draw the fence as a polygon; it is never approximated)")
    if not all(isinstance(p, dict) and isinstance(p.get("inclusion"), bool) for p in polygons):
        raise FenceFileError(f"{name}: each geoFence polygon must be an object with \"inclusion\": true or false")
    excluded = [p for p in polygons if not p["inclusion"]]
    if excluded:
        raise FenceFileError(f"{name}: {len(excluded)} geoFence exclusion polygon(s): the safety envelope has "
                             "no exclusion zones (remove them, or fly around them with a smaller fence)")
    if not polygons:
        raise FenceFileError(f"{name}: no geoFence polygon in the plan (its geoFence is empty)")
    if len(polygons) > 1:
        raise FenceFileError(f"{name}: {len(polygons)} geoFence inclusion polygons: the safety envelope holds "
                             "one fence polygon (keep one)")
    vertices = _qgc_points(polygons[0].get("polygon"), name)
    return FenceFile(path=name, what="QGroundControl geoFence inclusion polygon",
                     polygon_latlon_deg=_checked_polygon(vertices, name), home=_qgc_home(doc, name))


def _qgc_points(raw, name: str) -> list[tuple[float, float]]:
    """``[[lat, lon], ...]`` of a QGroundControl polygon."""
    if not isinstance(raw, list):
        raise FenceFileError(f"{name}: the geoFence polygon is not a list of [lat, lon] vertices")
    out = []
    for j, v in enumerate(raw):
        if (not isinstance(v, list) or len(v) != 2
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
            raise FenceFileError(f"{name}: geoFence vertex {j} {str(v)[:40]} is not [lat, lon] finite numbers")
        out.append((float(v[0]), float(v[1])))
    return out


def _qgc_home(doc: dict, name: str) -> tuple[float, float, float] | None:
    """``mission.plannedHomePosition`` ``[lat, lon, alt AMSL]``, or None when absent."""
    mission = doc.get("mission")
    raw = mission.get("plannedHomePosition") if isinstance(mission, dict) else None
    if raw is None:
        return None
    if (not isinstance(raw, list) or len(raw) != 3
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in raw)):
        raise FenceFileError(f"{name}: plannedHomePosition {str(raw)[:40]} is not [lat, lon, alt] finite numbers")
    _check_lat_lon(raw[0], raw[1], f"{name}: plannedHomePosition")
    return (float(raw[0]), float(raw[1]), float(raw[2]))


# ----------------------------------------------------------------------------------- checks
def _check_lat_lon(lat: float, lon: float, where: str) -> None:
    if not -90.0 <= lat <= 90.0:
        raise FenceFileError(f"{where}: latitude {lat} is outside -90..90")
    if not -180.0 <= lon <= 180.0:
        raise FenceFileError(f"{where}: longitude {lon} is outside -180..180")


def _checked_polygon(vertices, name: str) -> tuple[tuple[float, float], ...]:
    """The vertices, a closing repeat of the first dropped, checked for count and range."""
    if len(vertices) >= 2 and vertices[0] == vertices[-1]:
        vertices = vertices[:-1]
    if len(vertices) < 3:
        raise FenceFileError(f"{name}: the fence polygon has {len(vertices)} vertices, at least 3 are needed")
    if len(vertices) > MAX_FENCE_VERTICES:
        raise FenceFileError(f"{name}: the fence polygon has {len(vertices)} vertices, more than "
                             f"{MAX_FENCE_VERTICES} (simplify it where it was drawn)")
    for j, (lat, lon) in enumerate(vertices):
        _check_lat_lon(lat, lon, f"{name}: vertex {j}")
    return tuple(vertices)


def fence_in_mission_frame(fence: FenceFile, origin) -> tuple[tuple[float, float], ...]:
    """The polygon's vertices ``(east_m, north_m)`` about ``origin`` (``(lat_deg, lon_deg, alt_m)``).

    Each vertex is converted at the origin's altitude (as ``polygon_latlon_deg``): the altitude
    band is the plan's ``min_alt_m`` / ``max_alt_m``.

    Raises
    ------
    FenceFileError
        A vertex farther than :data:`MAX_FENCE_RADIUS_M` from the origin (the message names it
        and suggests swapped latitude and longitude).
    """
    frame = TangentFrame(origin)
    out = []
    for j, (lat, lon) in enumerate(fence.polygon_latlon_deg):
        east_m, north_m, _ = frame.geodetic_to_enu_m(lat, lon, float(origin[2]))
        dist_m = math.hypot(east_m, north_m)
        if not dist_m <= MAX_FENCE_RADIUS_M:
            raise FenceFileError(
                f"{fence.path}: vertex {j} (lat {lat:.7f}, lon {lon:.7f}) is {dist_m / 1000:.1f} km from the origin "
                f"({origin[0]:.7f}, {origin[1]:.7f}), more than {MAX_FENCE_RADIUS_M / 1000:g} km: latitude and "
                "longitude swapped (KML writes lon,lat; a .plan [lat, lon]) or the wrong origin?")
        out.append((float(east_m), float(north_m)))
    return tuple(out)
