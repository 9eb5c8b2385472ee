"""Configuration: JSON-Schema validation with defaults, plus the checks a schema cannot express.

The schema (``workflow/schemas/config.schema.yaml``) is the documentation of every key; the
Snakefile validates with it at parse time, and :func:`check_config` then checks what needs the
file system or the scene builder (texture files exist, key poses are enough, ...), so that a bad
config fails before any job runs and nothing is written.
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import jsonschema
import yaml

REPO_ROOT = Path(__file__).resolve().parents[2]
SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "config.schema.yaml"


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the key."""


def _extend_with_defaults(validator_class):
    validate_properties = validator_class.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, schema):
        if isinstance(instance, dict):
            for name, sub in properties.items():
                if "default" in sub and name not in instance:
                    instance[name] = copy.deepcopy(sub["default"])
        yield from validate_properties(validator, properties, instance, schema)

    return jsonschema.validators.extend(validator_class, {"properties": set_defaults})


_DefaultsValidator = _extend_with_defaults(jsonschema.Draft7Validator)


def load_schema(path: str | Path = SCHEMA_PATH) -> dict:
    return yaml.safe_load(Path(path).read_text())


def validate_config(
    config: dict[str, Any], schema_path: str | Path = SCHEMA_PATH
) -> dict[str, Any]:
    """Validate ``config`` in place against the schema, filling in defaults; returns it.

    Raises :class:`ConfigError` whose message names the offending key path.
    """
    schema = load_schema(schema_path)
    errors = sorted(_DefaultsValidator(schema).iter_errors(config), key=lambda e: list(e.path))
    if errors:
        e = errors[0]
        key = ".".join(str(p) for p in e.path) or "(top level)"
        raise ConfigError(f"config key '{key}': {e.message}")
    return config


def load_config(path: str | Path, check: bool = True) -> dict[str, Any]:
    """Read a YAML config, validate it with defaults and (optionally) run :func:`check_config`."""
    path = Path(path)
    config = yaml.safe_load(path.read_text()) or {}
    try:
        validate_config(config)
        if check:
            check_config(
                config, base_dir=path.parent.parent if path.parent.name == "config" else Path.cwd()
            )
    except ConfigError as e:
        raise ConfigError(f"{path}: {e}") from None
    return config


def check_config(config: dict[str, Any], base_dir: str | Path = ".") -> None:
    """Checks beyond the schema, for every dataset: the scene builds (synthetic) or the file exists (real).

    Raises :class:`ConfigError` naming ``datasets.<name>.<key>``.
    """
    base_dir = Path(base_dir)
    built: set[str] = set()  # building a scene takes seconds: check each distinct one once
    for name, ds in config.get("datasets", {}).items():
        if "recording" in ds:
            rec = Path(ds["recording"])
            if not rec.is_absolute():
                rec = base_dir / rec
            if not rec.exists():
                raise ConfigError(f"config key 'datasets.{name}.recording': no such file {rec}")
            if ds.get("calibration") and not (base_dir / ds["calibration"]).exists():
                raise ConfigError(
                    f"config key 'datasets.{name}.calibration': no such file {ds['calibration']}"
                )
            continue
        try:
            from evdense.sim.scene import load_scene
        except ImportError:  # simulator not installed in this build
            continue
        # speed and dynamic_range are range-checked by the schema and do not change the build.
        key = json.dumps(
            [ds.get(k) for k in ("scene", "duration", "seed")] + [config.get("simulator")],
            sort_keys=True,
            default=str,
        )
        if key in built:
            continue
        built.add(key)
        try:
            load_scene(ds, config.get("simulator", {}))
        except ValueError as e:
            raise ConfigError(f"config key 'datasets.{name}': {e}") from None
