"""Keep the config schema's descriptions and defaults equal to the stages' config dataclasses.

Every key of a stage's config section is written once, in its dataclass: the field's default and
the docstring under it. ``workflow/schemas/config.schema.yaml`` holds those again, beside what
only a schema says (types, ranges, enums), because the workflow validates a config and fills in
its defaults without importing any stage. This module writes the copies: after changing a field,
run ``python -m evdense.config_schema --write``; ``--check`` (and the test suite) fails while the
schema and a dataclass disagree on a key, a default or a description.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import importlib
import inspect
import json
import re
import sys
import textwrap
from pathlib import Path
from typing import Any

import yaml

from evdense.config import SCHEMA_PATH

SECTIONS: dict[str, str] = {
    "simulator.render": "evdense.sim.render:RenderConfig",
    "simulator.event_camera": "evdense.sim.esim:EventCameraConfig",
    "simulator.conventional_camera": "evdense.sim.conventional:ConventionalCameraConfig",
    "ingest": "evdense.io.ingest:IngestConfig",
    "events.window": "evdense.events.windows:WindowConfig",
    "events.voxel": "evdense.events.voxel:VoxelConfig",
    "events.summary": "evdense.events.summary:SummaryConfig",
    "reconstruct": "evdense.recon.config:ReconstructConfig",
    "mvs": "evdense.mvs.stage:MVSConfig",
    "mvs.oracle": "evdense.mvs.oracle:OracleConfig",
    "sfm": "evdense.sfm:SfmConfig",
    "evaluate": "evdense.evaluate.config:EvalConfig",
    "mesh": "evdense.mesh.stage:MeshConfig",
    "mesh.refine": "evdense.refine.photometric:RefineConfig",
    "mesh.texture": "evdense.texture.model:TextureConfig",
    "train": "evdense.training.train:TrainConfig",
}
"""Every config section backed by a dataclass: dotted path -> ``module:Class``."""

ONE_SIDED: dict[str, tuple[set[str], set[str]]] = {
    # the workflow's list of sources and the recipes they name; each source's ReconstructConfig
    # gets one method and one checkpoint from them
    "reconstruct": ({"methods", "presets", "checkpoints"}, {"method", "checkpoint"}),
    # the threshold of the oracle's evaluation, an argument of evaluate_mvs
    "mvs.oracle": ({"threshold"}, set()),
}
"""Keys on one side only, on purpose: section -> (schema only, dataclass only)."""


def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of the dataclass ``cls``, whitespace collapsed."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs: dict[str, str] = {}
    for a, b in zip(body, body[1:], strict=False):
        if (
            isinstance(a, ast.AnnAssign)
            and isinstance(a.target, ast.Name)
            and isinstance(b, ast.Expr)
            and isinstance(b.value, ast.Constant)
            and isinstance(b.value.value, str)
        ):
            docs[a.target.id] = _plain_text(b.value.value)
    return docs


def _plain_text(doc: str) -> str:
    """A docstring as a schema description: one line, without reST roles and literals."""
    doc = re.sub(r":\w+:`~?([^`]*)`", r"\1", doc).replace("``", "")
    return " ".join(doc.split())


def _plain(v: Any) -> Any:
    """A default as the schema holds it (tuples become lists)."""
    return json.loads(json.dumps(v, default=list))


def _section_class(path: str) -> type:
    module, name = SECTIONS[path].split(":")
    return getattr(importlib.import_module(module), name)


def sync_schema(schema: dict) -> list[str]:
    """Write every dataclass field's default and description into ``schema`` (in place).

    Returns what changed (``"mvs.window_radius: default"``, ...). Raises ``ValueError`` when a
    section's keys differ from its dataclass's fields (beyond :data:`ONE_SIDED`) or a field has
    no docstring: those need a person, not a copy.
    """
    changes: list[str] = []

    def visit(cls: type, props: dict, where: str) -> None:
        fields = {f.name for f in dataclasses.fields(cls)}
        docs = field_docs(cls)
        inst = cls()
        keys = {k for k in props["properties"] if f"{where}.{k}" not in SECTIONS}
        schema_only, class_only = ONE_SIDED.get(where, (set(), set()))
        if keys - schema_only != fields - class_only:
            raise ValueError(
                f"{where}: keys in the schema only {sorted(keys - schema_only - fields)}, "
                f"in {cls.__name__} only {sorted(fields - class_only - keys)}"
            )
        for k in sorted(keys - schema_only):
            if k not in docs:
                raise ValueError(f"{where}.{k}: {cls.__name__}.{k} has no docstring")
            entry = props["properties"][k]
            if entry.get("description") != docs[k]:
                entry["description"] = docs[k]
                changes.append(f"{where}.{k}: description")
            value = getattr(inst, k)
            if dataclasses.is_dataclass(value):
                visit(type(value), entry, f"{where}.{k}")
            elif entry.get("default", object()) != _plain(value):
                entry["default"] = _plain(value)
                changes.append(f"{where}.{k}: default")

    for path in sorted(SECTIONS):
        props = schema
        for part in path.split("."):
            props = props["properties"][part]
        visit(_section_class(path), props, path)
    return changes


class _Dumper(yaml.SafeDumper):
    pass


def _str(dumper: yaml.SafeDumper, s: str) -> yaml.ScalarNode:
    style = ">" if len(s) > 72 and "\n" not in s else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", s, style=style)


_Dumper.add_representer(str, _str)


def _one_line_descriptions(x: Any) -> None:
    if isinstance(x, dict):
        for k, v in x.items():
            if k == "description" and isinstance(v, str):
                x[k] = " ".join(v.split())
            else:
                _one_line_descriptions(v)
    elif isinstance(x, list):
        for v in x:
            _one_line_descriptions(v)


def dump_schema(schema: dict) -> str:
    """The schema as YAML: keys in their order, long descriptions folded at 100 columns."""
    _one_line_descriptions(schema)
    head = (
        "# Generated in part: the descriptions and defaults of the dataclass-backed sections come\n"
        "# from src/evdense (python -m evdense.config_schema --write); types, ranges and the\n"
        "# sections without a dataclass are edited here.\n"
    )
    return head + yaml.dump(
        schema, Dumper=_Dumper, sort_keys=False, width=100, allow_unicode=True, indent=2
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m evdense.config_schema", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--schema", default=str(SCHEMA_PATH))
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--check", action="store_true", help="fail when the schema is out of date")
    mode.add_argument("--write", action="store_true", help="rewrite the schema from the classes")
    args = ap.parse_args(argv)
    path = Path(args.schema)
    schema = yaml.safe_load(path.read_text())
    changes = sync_schema(schema)
    if args.check:
        for c in changes:
            print(f"{path}: out of date at {c}", file=sys.stderr)
        return 1 if changes else 0
    text = dump_schema(schema)
    if text != path.read_text():
        path.write_text(text)
        print(f"{path}: {len(changes)} values rewritten")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
