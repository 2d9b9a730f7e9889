"""The body of the two conformance tests (one per flavour): observe both, compare, check the list."""
from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from tests.conformance.compare import EVENT_ORDER, compare
from tests.conformance.known import KNOWN_DIFFERENCES, documented_keys
from tests.conformance.targets import observe_mock, observe_sitl

__all__ = ["DOC_PATH", "assert_conforms", "check_conformance"]

DOC_PATH = Path(__file__).resolve().parents[2] / "docs" / "interfaces.md"
_LOG = logging.getLogger("conformance")


def check_conformance(flavour: str) -> dict:
    """Run the script against the mock and one real SITL instance at once; compare.

    Returns
    -------
    dict
        ``mock`` and ``sitl`` observations, ``differences`` (list of
        :class:`~conformance.compare.Difference`), ``unexpected`` / ``missing`` keys against
        :data:`~conformance.known.KNOWN_DIFFERENCES`, and ``undocumented`` keys (known but not in
        docs/interfaces.md).
    """
    with ThreadPoolExecutor(max_workers=1) as pool:
        mock_future = pool.submit(observe_mock, flavour)
        sitl = observe_sitl(flavour)
        mock = mock_future.result()
    diffs = compare(mock, sitl)
    for d in diffs:
        _LOG.info("%s difference: %s", flavour, d)
    keys = {d.key for d in diffs}
    known = set(KNOWN_DIFFERENCES[flavour])
    return {"mock": mock, "sitl": sitl, "differences": diffs, "unexpected": sorted(keys - known),
            "missing": sorted(known - keys), "undocumented": sorted(known - documented_keys(DOC_PATH, flavour))}


def assert_conforms(flavour: str) -> None:
    """Run :func:`check_conformance` and assert: no new difference, no listed one gone, every
    listed one documented, and the whole scripted sequence ran through against both."""
    result = check_conformance(flavour)
    listing = "\n".join(str(d) for d in result["differences"])
    assert result["unexpected"] == [], f"new mock/SITL differences (fix the mock or document them):\n{listing}"
    assert result["missing"] == [], f"known differences no longer seen (remove them from known.py and docs):\n{listing}"
    assert result["undocumented"] == [], "known differences missing from docs/interfaces.md"
    for obs in (result["mock"], result["sitl"]):   # the sequence really ran through, in both
        assert all(name in obs.events_s for name in EVENT_ORDER)
        assert obs.acks["arm"] == obs.acks["takeoff"] == obs.acks["land"] == 0
        assert obs.details["target"]["reached"] and obs.details["mission_download"]["waypoints_match"]
