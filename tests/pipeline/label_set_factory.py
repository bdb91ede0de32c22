"""Label set files for tests: a valid set of any size, written as YAML."""

from __future__ import annotations

from pathlib import Path

import yaml

# The maps of semantic-kitti-api's config file, for the importer's tests.
SEMANTIC_KITTI_YAML = Path(__file__).parent / "fixtures" / "semantic-kitti.yaml"


def label_set_data(n_classes: int, n_ground: int = 1, name: str = "custom") -> dict:
    """A valid label set mapping: n_classes - n_ground things, then n_ground ground classes."""
    classes = []
    for i in range(n_classes):
        ground = i >= n_classes - n_ground
        classes.append({
            "name": f"class-{i:02d}", "colour": [(37 * i) % 256, (91 * i) % 256, (53 * i) % 256],
            "key": f"F{i}", "reads": [1000 + i], "writes": 1000 + i,
            "kind": "stuff" if ground else "thing", "ground": ground,
        })
    return {"name": name, "classes": classes, "unlabelled_ids": [0]}


def write_label_set(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
