"""Configuration: JSON-Schema validation with defaults, plus the checks a schema cannot express.

The schema (``workflow/schemas/config.schema.yaml``) is the documentation of every key; the
Snakefile validates with it at parse time, and :func:`check_config` then checks what needs the
file system or the scene builder (texture files exist, key poses are enough, ...), so that a bad
config fails before any job runs and nothing is written.
"""

from __future__ import annotations

import copy
import dataclasses
import json
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import jsonschema
import yaml

REPO_ROOT = Path(__file__).resolve().parents[2]
SCHEMA_PATH = REPO_ROOT / "workflow" / "schemas" / "config.schema.yaml"


T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration value is invalid; the message names the key."""


def _is_map(sub: dict[str, Any]) -> bool:
    """A schema of a free-keyed mapping with default entries (no fixed ``properties``)."""
    return (
        sub.get("type") == "object"
        and isinstance(sub.get("default"), dict)
        and "properties" not in sub
        and isinstance(sub.get("additionalProperties"), dict)
    )


def _extend_with_defaults(validator_class):
    validate_properties = validator_class.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, schema):
        if isinstance(instance, dict):
            for name, sub in properties.items():
                if "default" not in sub:
                    continue
                if name not in instance:
                    instance[name] = copy.deepcopy(sub["default"])
                elif _is_map(sub) and isinstance(instance[name], dict):
                    # a map-valued key (checkpoints, presets): entries given are added to the
                    # default entries, so naming one does not drop the others
                    for k, v in sub["default"].items():
                        instance[name].setdefault(k, copy.deepcopy(v))
        yield from validate_properties(validator, properties, instance, schema)

    return jsonschema.validators.extend(validator_class, {"properties": set_defaults})


_DefaultsValidator = _extend_with_defaults(jsonschema.Draft7Validator)


def section_from_dict(
    cls: type[T], d: Mapping[str, Any] | T | None, path: str, drop_none: bool = False
) -> T:
    """Build the dataclass ``cls`` from its config section ``d`` at ``path`` (``"mvs"``,
    ``"simulator.event_camera"``, ...): missing keys take the defaults, nested dataclasses are
    built from their sub-sections, NumPy scalars (Paramspace sweeps) become Python numbers, and
    ``drop_none`` lets a ``null`` value mean "the default". The built object's ``check()`` runs
    when it has one. Unknown keys raise ``ValueError`` naming the path, the keys and the known ones.
    This is the one ``from_dict`` of every stage's config.
    """
    if isinstance(d, cls):
        return d
    d = dict(d or {})
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - set(fields))
    if unknown:
        raise ValueError(f"{path}: unknown keys {unknown} (known: {sorted(fields)})")
    kwargs: dict[str, Any] = {}
    for k, v in d.items():
        if v is None and drop_none:
            continue
        f = fields[k]
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
        if dataclasses.is_dataclass(default) and not isinstance(v, type(default)):
            v = section_from_dict(type(default), v, f"{path}.{k}", drop_none)
        elif isinstance(v, list):
            v = [
                x.item() if hasattr(x, "item") and not isinstance(x, str | bytes) else x for x in v
            ]
        elif hasattr(v, "item") and hasattr(v, "dtype"):
            v = v.item()
        kwargs[k] = v
    conf = cls(**kwargs)
    check = getattr(conf, "check", None)
    if callable(check):
        check()
    return conf


def load_schema(path: str | Path = SCHEMA_PATH) -> dict:
    return yaml.safe_load(Path(path).read_text())


def validate_config(
    config: dict[str, Any], schema_path: str | Path = SCHEMA_PATH, partial: bool = False
) -> dict[str, Any]:
    """Validate ``config`` in place against the schema, filling in defaults; returns it.

    ``partial``: only the sections ``config`` holds are checked (a stage run alone), so the
    top-level keys the schema requires may be missing.
    Raises :class:`ConfigError` whose message names the offending key path.
    """
    schema = load_schema(schema_path)
    if partial:
        schema = {**schema, "required": []}
    errors = sorted(_DefaultsValidator(schema).iter_errors(config), key=lambda e: list(e.path))
    if errors:
        e = errors[0]
        key = ".".join(str(p) for p in e.path) or "(top level)"
        if "propertyNames" in list(e.schema_path):
            key, msg = (
                f"{key}.{e.instance}",
                "not a valid name: use letters, digits, _ . - (it becomes a folder name)",
            )
        else:
            msg = e.message
        raise ConfigError(f"config key '{key}': {msg}")
    sort_keys_in_place(config)
    return config


def fill_section(name: str, section: dict[str, Any] | None) -> dict[str, Any]:
    """The config section ``name`` validated against its part of the schema, with its defaults
    filled in (a copy): what a stage run alone, outside the workflow, starts from.

    Raises :class:`ConfigError` whose message names the offending key path.
    """
    return validate_config({name: copy.deepcopy(section or {})}, partial=True)[name]


def sort_keys_in_place(d: dict[str, Any]) -> None:
    """Order the keys of ``d`` and of every mapping inside it (lists keep their order), so that
    two configs that differ only in key order compare equal as text (Snakemake's rule params)."""
    items = sorted(d.items(), key=lambda kv: str(kv[0]))
    d.clear()
    for k, v in items:
        if isinstance(v, dict):
            sort_keys_in_place(v)
        elif isinstance(v, list):
            for x in v:
                if isinstance(x, dict):
                    sort_keys_in_place(x)
        d[k] = v


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


def _num_label(v: float) -> str:
    return f"{v:g}".replace(".", "p").replace("+", "")


def sweep_datasets(config: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The datasets generated by the ``sweep`` section: ``<scene>_s<speed>_dr<dynamic_range>``."""
    sw = config.get("sweep") or {}
    out: dict[str, dict[str, Any]] = {}
    speeds, drs = sw.get("speeds", [1]), sw.get("dynamic_ranges", [1])
    if sw.get("grid", "axes") == "product":
        pairs = [(s, d) for s in speeds for d in drs]
    else:
        pairs = [(s, 1) for s in speeds] + [(1, d) for d in drs]
    for scene in sw.get("scenes", []):
        base = Path(scene).stem
        for speed, dr in dict.fromkeys(pairs):
            ds: dict[str, Any] = {
                "scene": scene,
                "speed": float(speed),
                "dynamic_range": float(dr),
                "seed": 0,
                "format": "auto",
            }
            if "duration" in sw:
                ds["duration"] = float(sw["duration"])
            out[f"{base}_s{_num_label(speed)}_dr{_num_label(dr)}"] = ds
    return out


def all_datasets(config: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The datasets listed under ``datasets`` plus those generated by ``sweep`` (listed ones win)."""
    return {**sweep_datasets(config), **config.get("datasets", {})}


def check_config(
    config: dict[str, Any],
    base_dir: str | Path = ".",
    build_scene: Callable[[dict[str, Any], dict[str, Any]], Any] | None = None,
) -> None:
    """Checks beyond the schema, for every dataset: the files of a recording exist and its GT keys
    make sense; with ``build_scene`` (the simulator's :func:`evdense.sim.scene.load_scene`, which
    the workflow passes; this module imports no stage) every synthetic scene builds.

    Raises :class:`ConfigError` naming ``datasets.<name>.<key>``, or ``datasets`` when there is
    nothing to reconstruct.
    """
    if not all_datasets(config):
        raise ConfigError(
            "config key 'datasets': no datasets to reconstruct (name at least one under "
            "`datasets`, or give a `sweep`)"
        )
    base_dir = Path(base_dir)
    built: set[str] = set()  # building a scene takes seconds: check each distinct one once
    for name, ds in all_datasets(config).items():
        if "recording" in ds:
            rec = Path(ds["recording"])
            if not rec.is_absolute():
                rec = base_dir / rec
            if not rec.exists():
                raise ConfigError(f"config key 'datasets.{name}.recording': no such file {rec}")
            if ds.get("gt_mesh") and ds.get("gt_depth"):
                raise ConfigError(
                    f"config key 'datasets.{name}.gt_depth': give gt_mesh or gt_depth, not both"
                )
            for key in ("calibration", "gt_mesh", "gt_trajectory", "gt_depth"):
                if ds.get(key) and not (base_dir / ds[key]).exists():
                    raise ConfigError(f"config key 'datasets.{name}.{key}': no such file {ds[key]}")
            continue
        for key in ("gt_mesh", "gt_trajectory", "gt_depth"):
            if ds.get(key):
                raise ConfigError(f"config key 'datasets.{name}.{key}': only for a recording (a "
                                  "synthetic scene has its own GT)")  # fmt: skip
        if build_scene is None:
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
            build_scene(ds, config.get("simulator", {}))
        except ValueError as e:
            raise ConfigError(f"config key 'datasets.{name}': {e}") from None
