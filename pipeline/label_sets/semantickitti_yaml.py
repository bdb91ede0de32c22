"""Import a semantic-kitti.yaml style file (labels, color_map, learning_map) as a LabelSet.

Each learning-map index other than the ignored ones becomes a class, in index order: it reads
every id the learning map sends to it and writes `learning_map_inv`'s id (the smallest id when
the file has no inverse map). Colours come from `color_map`, which that format gives as BGR.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from pipeline.errors import ConfigError
from pipeline.label_sets.load import validate_label_set
from pipeline.label_sets.model import LabelSet

# What the format does not say: SemanticKITTI's own thing and ground classes (its paper's split).
_THINGS = frozenset({"car", "bicycle", "motorcycle", "truck", "other-vehicle", "person", "bicyclist",
                     "motorcyclist"})
_GROUND = frozenset({"road", "parking", "sidewalk", "other-ground", "terrain"})
# Hotkeys handed out in class order; the viewer's own keys (A, D, S, Z, H, P) are left out.
_KEYS = "1234567890QWERTYUIOFGJKLXCVBNM"


def from_semantickitti_yaml(path: str | Path, name: str | None = None) -> LabelSet:
    """The label set of a semantic-kitti.yaml style file; ConfigError naming the file and field."""
    path = Path(path)
    data = _read(path)
    labels = _int_map(data, "labels", path)
    colours = _int_map(data, "color_map", path)
    learning = _int_map(data, "learning_map", path)
    ignored = {int(k) for k, v in (data.get("learning_ignore") or {0: True}).items() if v}
    inverse = _int_map(data, "learning_map_inv", path) if "learning_map_inv" in data else {}
    classes = []
    for n, idx in enumerate(sorted(set(learning.values()) - ignored)):
        reads = sorted(i for i, v in learning.items() if v == idx)
        writes = inverse.get(idx, reads[0])
        cname = _lookup(labels, writes, "labels", path)
        bgr = _lookup(colours, writes, "color_map", path)
        moving = next((i for i in reads if labels.get(i) == f"moving-{cname}"), None)
        classes.append({
            "name": cname, "colour": bgr[::-1] if isinstance(bgr, list) else bgr, "key": _KEYS[n] if n < len(_KEYS) else None,
            "reads": reads, "writes": writes, "moving": moving,
            "kind": "thing" if cname in _THINGS or moving is not None else "stuff", "ground": cname in _GROUND,
        })
    unlabelled = sorted(i for i, v in learning.items() if v in ignored)
    label_set = {"name": name or path.stem.lower(), "classes": classes, "unlabelled_ids": unlabelled,
                 "description": f"imported from {path.name}"}
    return validate_label_set(label_set, str(path))


def _read(path: Path) -> dict:
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping with labels, color_map and learning_map")
    return data


def _int_map(data: dict, field: str, path: Path) -> dict:
    value = data.get(field)
    if not isinstance(value, dict) or not value:
        raise ConfigError(f"{path}: field {field}: missing or not a mapping of ids")
    try:
        return {int(k): v if field in ("labels", "color_map") else int(v) for k, v in value.items()}
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: field {field}: ids must be integers ({exc})") from exc


def _lookup(table: dict, key: int, field: str, path: Path) -> object:
    if key not in table:
        raise ConfigError(f"{path}: field {field}: no entry for id {key}")
    return table[key]
