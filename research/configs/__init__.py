"""Named experiment configs: the YAML files beside this module, loaded over a config class.

A file holds overrides of the class's defaults only (nested for `training`); several files apply
in order, then `KEY=VALUE` overrides (dotted keys for nested fields, values parsed as YAML).
Each run writes the config it used into its JSON.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

from pipeline.config import merge_nested, read_yaml_mapping
from pipeline.errors import ConfigError

CONFIG_DIR = Path(__file__).resolve().parent
T = TypeVar("T", bound=BaseModel)


def config_names() -> list[str]:
    """The named configs shipped with the package."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))


def _read(name: str) -> dict[str, Any]:
    path = Path(name)
    if not path.suffix:
        path = CONFIG_DIR / f"{name}.yaml"
        if not path.is_file():
            raise ConfigError(f"no experiment config named {name!r}; named: {', '.join(config_names())}")
    return read_yaml_mapping(path, "an experiment config must be a mapping of fields")


def _assignment(item: str) -> dict[str, Any]:
    """'training.lr=0.01' -> {"training": {"lr": 0.01}}."""
    key, sep, raw = item.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"--set {item!r}: expected KEY=VALUE")
    try:
        value: Any = yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {item!r}: {exc}") from exc
    for part in reversed(key.strip().split(".")):
        value = {part: value}
    return value


def load_experiment_config(cls: type[T], names: Sequence[str] = (), sets: Sequence[str] = ()) -> T:
    """`cls` with the named configs (a name in research/configs, or a .yaml path) and the
    KEY=VALUE overrides applied in order; a bad field is a ConfigError naming it."""
    # onto the class's own defaults, so that a nested override keeps the other fields of a nested
    # default that differs from its type's (DefaultModelConfig.training's step budget, say)
    data: dict[str, Any] = cls().model_dump()
    for name in names:
        data = merge_nested(data, _read(name))
    for item in sets:
        data = merge_nested(data, _assignment(item))
    try:
        return cls.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        field = ".".join(str(p) for p in first["loc"])
        where = ", ".join(names) or "defaults"
        raise ConfigError(f"{where}: field {field}: {first['msg']}") from exc
