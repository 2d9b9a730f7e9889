"""The known, accepted differences between the mock and real SITL (keys of :func:`.compare.compare`).

Each entry is documented, with its reason, in docs/interfaces.md, section "Mock vs real SITL";
the conformance tests fail when a difference appears that is not listed here, when a listed one
disappears (then remove it here and in the docs), and when the docs do not list a key.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["DOC_SECTION", "KNOWN_DIFFERENCES", "documented_keys"]

#: flavour -> {difference key: why it is acceptable}
KNOWN_DIFFERENCES = {
    "ardupilot": {
        "mission:request_kind": "ArduCopter asks for upload items with the legacy MISSION_REQUEST, the mock "
                                "with MISSION_REQUEST_INT; both accept MISSION_ITEM_INT; the coordinator "
                                "uploads no missions",
        "message:MISSION_REQUEST": "same cause as mission:request_kind",
        "mission:frames": "ArduCopter returns the non-INT frame number (3) in MISSION_ITEM_INT, the mock "
                          "the INT frame it was given (6); same meaning, positions identical",
    },
    "px4": {
        "mission:request_kind": "PX4 asks for the first upload item with the legacy MISSION_REQUEST and "
                                "for the rest with MISSION_REQUEST_INT, the mock always with "
                                "MISSION_REQUEST_INT; the coordinator uploads no missions",
        "message:MISSION_REQUEST": "same cause as mission:request_kind",
        "message:MISSION_CURRENT": "PX4 streams it by default; the mock streams only what the coordinator "
                                   "and the tests use (it can be enabled with SET_MESSAGE_INTERVAL)",
        "message:SYSTEM_TIME": "PX4 streams it by default; the mock has no clock-sync message (nothing in "
                               "swarmseek reads it)",
    },
}

DOC_SECTION = "## Mock vs real SITL"


def documented_keys(doc_path: Path, flavour: str) -> set[str]:
    """Difference keys listed for ``flavour`` in the docs table (rows ``| `key` | ... |``).

    A row names its flavour in the key cell as ``px4: `key``` / ``ardupilot: `key``` or
    ``both: `key``` (both flavours).
    """
    text = Path(doc_path).read_text()
    start = text.index(DOC_SECTION)
    end = text.find("\n## ", start + len(DOC_SECTION))
    keys = set()
    for line in text[start:end if end > 0 else len(text)].splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or ":" not in cells[0] or "`" not in cells[0]:
            continue
        who, _, key = cells[0].partition(":")
        if who.strip() in (flavour, "both"):
            keys.add(key.strip().strip("`"))
    return keys
