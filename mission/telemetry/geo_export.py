"""A flown mission as KML (Google Earth) or GeoJSON (QGIS), from its mission log.

:func:`mission_geometry` reads the mission log's records (the ``plan`` record: origin, geofence,
seeking start; ``status`` and ``iteration`` records: every vehicle's telemetry track and the
formation centre; ``summary``: the estimate and its 95 % region; ``truth``: the true source of a
simulated run) and converts them from the mission frame to WGS-84 with
:func:`formation.geodesy.enu_to_geodetic` (pymap3d). :func:`write_kml` and :func:`write_geojson`
write them.

Altitudes: the mission origin's altitude is above mean sea level (``docs/mission.md``), so are
the altitudes converted about it. KML takes them as they are (``altitudeMode`` ``absolute``:
above sea level). GeoJSON (RFC 7946, section 4) defines a third coordinate as height above the
WGS-84 ellipsoid, which these are not: its positions are ``[lon, lat]`` and the altitudes (AMSL)
are in each feature's properties (``alt_m_amsl``), never passed off as ellipsoidal heights.

The estimate's 95 % region is a sphere; both formats draw its horizontal section as a polygon of
:data:`REGION_VERTICES` vertices on the circle, with the exact radius in the properties
(``radius_m``).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from formation.geodesy import enu_to_geodetic

__all__ = ["GeoExportError", "REGION_VERTICES", "mission_geometry", "geojson_document", "kml_document",
           "write_geojson", "write_kml"]

#: vertices of the polygon drawn on the 95 % region's circle
REGION_VERTICES = 72
_KML_NS = "http://www.opengis.net/kml/2.2"
#: decimals of latitude and longitude written (1e-8 deg: about 1 mm)
_DEG_DECIMALS = 8


class GeoExportError(ValueError):
    """A mission log that holds nothing to export (no plan record, no origin)."""


def _enu_array(value, what: str) -> np.ndarray | None:
    if value is None:
        return None
    arr = np.asarray(value, dtype=float)
    if arr.shape[-1:] != (3,) or not np.all(np.isfinite(arr)):
        raise GeoExportError(f"the mission log's {what} is not east, north, up metres: {str(value)[:60]}")
    return arr


def _plan_of(records: list[dict]) -> dict:
    plans = [r.get("plan") for r in records if r.get("type") == "plan" and isinstance(r.get("plan"), dict)]
    if not plans:
        raise GeoExportError("the mission log has no plan record (not a swarmseek mission log, or cut short "
                             "before the mission started)")
    plan = plans[0]
    origin = plan.get("origin")
    if (not isinstance(origin, list) or len(origin) != 3
            or not all(isinstance(v, (int, float)) and np.isfinite(v) for v in origin)):
        raise GeoExportError(f"the mission log's plan record has no usable origin: {str(origin)[:60]}")
    return plan


def _vehicle_tracks(records: list[dict]) -> dict[str, dict]:
    """``{sysid: {"id", "t_s" (T,), "enu" (T, 3)}}`` from the telemetry of status and iteration records."""
    samples: dict[str, list] = {}
    names: dict[str, str] = {}
    for r in records:
        t_s = r.get("t_s")
        if r.get("type") == "status":
            for v in r.get("vehicles") or []:
                if isinstance(v, dict) and v.get("position_enu") is not None:
                    samples.setdefault(str(v.get("sysid")), []).append((t_s, v["position_enu"]))
                    names.setdefault(str(v.get("sysid")), str(v.get("id", "")))
        elif r.get("type") == "iteration":
            for s, p in (r.get("positions_enu") or {}).items():
                samples.setdefault(str(s), []).append((t_s, p))
    out = {}
    for sysid, rows in samples.items():
        rows = sorted((float(t), p) for t, p in rows if t is not None and p is not None and len(p) == 3)
        if rows:
            out[sysid] = {"id": names.get(sysid, ""), "t_s": np.array([t for t, _ in rows]),
                          "enu": _enu_array([p for _, p in rows], f"vehicle {sysid} position")}
    return dict(sorted(out.items(), key=lambda kv: (len(kv[0]), kv[0])))


def mission_geometry(records: list[dict]) -> dict:
    """What a map shows of a flown mission, in the mission frame (ENU metres).

    Returns
    -------
    dict
        ``origin`` (lat_deg, lon_deg, alt_m AMSL), ``fence_en_m`` (K, 2) counter-clockwise or
        None, ``min_alt_m`` / ``max_alt_m`` (mission up), ``fence_source`` (str), ``start_enu``
        (3,), ``vehicles`` (:func:`_vehicle_tracks`), ``centre_enu`` (T, 3) or None,
        ``estimate_enu`` (3,) or None, ``region95_m`` and ``basis``, ``true_source_enu`` or None,
        ``fleet``, ``outcome``, ``message``.

    Raises
    ------
    GeoExportError
        No plan record or no usable origin, or a malformed position.
    """
    plan = _plan_of(records)
    gf = plan.get("geofence") or {}
    fence = _fence_ccw(gf.get("polygon_en_m"))
    seeking = plan.get("seeking") or {}
    start = seeking.get("start_enu_m") or [0.0, 0.0, float(seeking.get("altitude_m", 10.0))]
    its = [r for r in records if r.get("type") == "iteration"]
    centre = [r.get("centre_enu") for r in its] + ([its[-1].get("new_centre_enu")] if its else [])
    centre = [c for c in centre if c is not None]
    summary = next((r for r in reversed(records) if r.get("type") == "summary"), {})
    source = summary if summary.get("estimate_enu") is not None else (its[-1] if its else {})
    truth = next((r for r in reversed(records) if r.get("type") == "truth"), {})
    region = source.get("estimate_region95_m")
    return {"origin": tuple(float(v) for v in plan["origin"]), "fleet": str(plan.get("fleet", "")),
            "fence_en_m": fence, "min_alt_m": gf.get("min_alt_m"), "max_alt_m": gf.get("max_alt_m"),
            "fence_source": str(gf.get("source") or ""), "start_enu": _enu_array(start, "seeking start"),
            "vehicles": _vehicle_tracks(records), "centre_enu": _enu_array(centre, "centre track") if centre else None,
            "estimate_enu": _enu_array(source.get("estimate_enu"), "estimate"),
            "region95_m": None if region is None else float(region), "basis": source.get("estimate_basis"),
            "true_source_enu": _enu_array(truth.get("source_enu"), "true source"),
            "outcome": summary.get("outcome", "no summary (interrupted?)"), "message": summary.get("message", "")}


def _fence_ccw(polygon) -> np.ndarray | None:
    """The fence's vertices ``(K, 2)``, counter-clockwise (RFC 7946's right-hand rule), or None."""
    if not polygon:
        return None
    poly = np.asarray(polygon, dtype=float)
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3 or not np.all(np.isfinite(poly)):
        raise GeoExportError(f"the mission log's geofence polygon is not (east, north) vertices: {str(polygon)[:60]}")
    x, y = poly[:, 0], poly[:, 1]
    area = 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    return poly if area > 0 else poly[::-1].copy()


def _region_ring_enu(centre_enu: np.ndarray, radius_m: float) -> np.ndarray:
    """The 95 % region's horizontal circle as a closed ring ``(REGION_VERTICES + 1, 3)``, counter-clockwise."""
    a = np.linspace(0.0, 2.0 * np.pi, REGION_VERTICES + 1)
    a[-1] = 0.0  # closed exactly
    ring = np.repeat(centre_enu[None, :], REGION_VERTICES + 1, axis=0)
    ring[:, 0] += radius_m * np.cos(a)
    ring[:, 1] += radius_m * np.sin(a)
    return ring


def _to_geodetic(enu: np.ndarray, origin) -> np.ndarray:
    """``(..., 3)`` ENU -> ``(..., 3)`` (lon_deg, lat_deg, alt_m AMSL), rounded as written."""
    lat, lon, alt = enu_to_geodetic(enu, origin)
    return np.stack([np.round(lon, _DEG_DECIMALS), np.round(lat, _DEG_DECIMALS), np.round(alt, 3)], axis=-1)


def _items(geo: dict) -> list[dict]:
    """Each map item: ``name``, ``kind``, ``shape`` (point, line, ring), ``lonlatalt`` (N, 3), ``props``."""
    o = geo["origin"]
    items = []
    if geo["fence_en_m"] is not None:
        ring = np.vstack([geo["fence_en_m"], geo["fence_en_m"][:1]])
        enu = np.column_stack([ring, np.zeros(len(ring))])
        items.append({"name": "geofence", "kind": "geofence", "shape": "ring", "lonlatalt": _to_geodetic(enu, o),
                      "props": {"min_alt_m": geo["min_alt_m"], "max_alt_m": geo["max_alt_m"],
                                "altitudes": "min_alt_m/max_alt_m: metres up about the origin",
                                "source": geo["fence_source"] or "the plan"}})
    items.append({"name": "origin", "kind": "origin", "shape": "point",
                  "lonlatalt": np.array([[o[1], o[0], o[2]]]), "props": {}})
    items.append({"name": "start", "kind": "start", "shape": "point",
                  "lonlatalt": _to_geodetic(geo["start_enu"][None, :], o), "props": {}})
    for sysid, tr in geo["vehicles"].items():
        items.append({"name": f"vehicle {sysid}" + (f" ({tr['id']})" if tr["id"] else ""), "kind": "track",
                      "shape": "line" if len(tr["enu"]) > 1 else "point",
                      "lonlatalt": _to_geodetic(tr["enu"], o),
                      "props": {"sysid": int(sysid) if sysid.isdigit() else sysid, "id": tr["id"],
                                "t_start_s": float(tr["t_s"][0]), "t_end_s": float(tr["t_s"][-1])}})
    if geo["centre_enu"] is not None and len(geo["centre_enu"]) > 1:
        items.append({"name": "formation centre", "kind": "centre", "shape": "line",
                      "lonlatalt": _to_geodetic(geo["centre_enu"], o), "props": {}})
    if geo["estimate_enu"] is not None:
        items.append({"name": "estimate", "kind": "estimate", "shape": "point",
                      "lonlatalt": _to_geodetic(geo["estimate_enu"][None, :], o),
                      "props": {"region95_m": geo["region95_m"], "basis": geo["basis"], "outcome": geo["outcome"]}})
        if geo["region95_m"] is not None and geo["region95_m"] > 0:
            items.append({"name": "estimate 95 % region", "kind": "region95", "shape": "ring",
                          "lonlatalt": _to_geodetic(_region_ring_enu(geo["estimate_enu"], geo["region95_m"]), o),
                          "props": {"radius_m": geo["region95_m"],
                                    "drawn_as": f"{REGION_VERTICES} vertices on the sphere's horizontal circle"}})
    if geo["true_source_enu"] is not None:
        items.append({"name": "true source (simulation)", "kind": "true_source", "shape": "point",
                      "lonlatalt": _to_geodetic(geo["true_source_enu"][None, :], o), "props": {}})
    return items


def geojson_document(geo: dict) -> dict:
    """An RFC 7946 FeatureCollection of :func:`mission_geometry` (``[lon, lat]`` positions, the
    altitudes AMSL in ``alt_m_amsl``)."""
    features = []
    for it in _items(geo):
        lla = it["lonlatalt"]
        pos = [[float(p[0]), float(p[1])] for p in lla]
        alts = [float(p[2]) for p in lla]
        if it["shape"] == "point":
            geometry, alt = {"type": "Point", "coordinates": pos[0]}, alts[0]
        elif it["shape"] == "line":
            geometry, alt = {"type": "LineString", "coordinates": pos}, alts
        else:
            geometry, alt = {"type": "Polygon", "coordinates": [pos]}, (alts[0] if it["kind"] == "region95" else None)
        props = {"name": it["name"], "kind": it["kind"], **it["props"]}
        if alt is not None:
            props["alt_m_amsl"] = alt
        features.append({"type": "Feature", "geometry": geometry, "properties": props})
    return {"type": "FeatureCollection", "features": features,
            "swarmseek": {"fleet": geo["fleet"], "origin": list(geo["origin"]), "outcome": geo["outcome"],
                          "message": geo["message"]}}


def kml_document(geo: dict) -> bytes:
    """A KML 2.2 document of :func:`mission_geometry` (altitudes ``absolute``: above sea level)."""
    from lxml import etree

    def sub(parent, tag, text=None):
        el = etree.SubElement(parent, f"{{{_KML_NS}}}{tag}")
        if text is not None:
            el.text = str(text)
        return el

    root = etree.Element(f"{{{_KML_NS}}}kml", nsmap={None: _KML_NS})
    doc = sub(root, "Document")
    sub(doc, "name", f"swarmseek mission, fleet {geo['fleet']}: {geo['outcome']}")
    if geo["message"]:
        sub(doc, "description", geo["message"])
    for it in _items(geo):
        pm = sub(doc, "Placemark")
        sub(pm, "name", it["name"])
        data = sub(pm, "ExtendedData")
        for key, value in {"kind": it["kind"], **it["props"]}.items():
            d = sub(data, "Data")
            d.set("name", key)
            sub(d, "value", "" if value is None else value)
        coords = " ".join(f"{p[0]:.{_DEG_DECIMALS}f},{p[1]:.{_DEG_DECIMALS}f},{p[2]:.3f}" for p in it["lonlatalt"])
        if it["shape"] == "point":
            geom = sub(pm, "Point")
        elif it["shape"] == "line":
            geom = sub(pm, "LineString")
        else:
            geom = sub(pm, "Polygon")
        sub(geom, "altitudeMode", "clampToGround" if it["kind"] == "geofence" else "absolute")
        target = geom if it["shape"] != "ring" else sub(sub(sub(geom, "outerBoundaryIs"), "LinearRing"), "coordinates")
        if it["shape"] != "ring":
            sub(target, "coordinates", coords)
        else:
            target.text = coords
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def write_geojson(geo: dict, path: str | Path) -> Path:
    """Write :func:`geojson_document` to ``path`` (UTF-8 JSON); returns the path."""
    path = Path(path)
    path.write_text(json.dumps(geojson_document(geo), indent=1) + "\n", encoding="utf-8")
    return path


def write_kml(geo: dict, path: str | Path) -> Path:
    """Write :func:`kml_document` to ``path``; returns the path."""
    path = Path(path)
    path.write_bytes(kml_document(geo))
    return path
