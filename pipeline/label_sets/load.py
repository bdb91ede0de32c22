"""Label sets from YAML: the presets shipped beside this module, or any file by path."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import yaml
from pydantic import ValidationError

from pipeline.errors import ConfigError
from pipeline.label_sets.model import LabelSet

PRESET_DIR = Path(__file__).resolve().parent
DEFAULT_LABEL_SET = "paper"


def preset_names() -> tuple[str, ...]:
    """The presets shipped with tracklabel, the default first."""
    names = sorted(p.stem for p in PRESET_DIR.glob("*.yaml"))
    return (DEFAULT_LABEL_SET, *(n for n in names if n != DEFAULT_LABEL_SET))


@cache
def preset(name: str) -> LabelSet:
    """A shipped label set by name; ConfigError naming the presets when there is none."""
    if name not in preset_names():
        raise ConfigError(f"unknown label set {name!r}; presets: {', '.join(preset_names())}")
    return read_label_set(PRESET_DIR / f"{name}.yaml")


def load_label_set(name_or_path: str | Path) -> LabelSet:
    """A preset by name, or a label set file by path (anything with a '/' or ending in .yaml)."""
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or "/" in text or text.endswith((".yaml", ".yml")):
        return read_label_set(Path(name_or_path))
    return preset(text)


def read_label_set(path: Path) -> LabelSet:
    """A label set file; ConfigError naming the file and the field when it is not valid."""
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read label set: {exc}") from exc
    return validate_label_set(data, str(path))


def validate_label_set(data: object, where: str) -> LabelSet:
    """`data` (a parsed mapping) as a LabelSet; ConfigError '<where>: field <f>: <why>' otherwise."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: a label set is a mapping with name and classes")
    try:
        return LabelSet.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{where}: {_first_error(exc, data)}") from exc


def _first_error(exc: ValidationError, data: dict) -> str:
    err = exc.errors()[0]
    msg = str(err["msg"]).removeprefix("Value error, ")
    loc = list(err["loc"])
    if not loc:  # the set's own checks begin their message with the field
        return f"field {msg}"
    if len(loc) >= 2 and loc[0] == "classes" and isinstance(loc[1], int):
        loc[1] = f"{loc[1]} ({_class_name(data, loc[1])})"
    return f"field {'.'.join(str(p) for p in loc)}: {msg}"


def _class_name(data: dict, i: int) -> str:
    classes = data.get("classes")
    entry = classes[i] if isinstance(classes, list) and i < len(classes) else None
    return str(entry.get("name", "?")) if isinstance(entry, dict) else "?"


def dump_label_set(label_set: LabelSet) -> str:
    """The YAML text of a label set (what `read_label_set` reads back)."""
    return yaml.safe_dump(label_set.model_dump(mode="json"), sort_keys=False, default_flow_style=None)
