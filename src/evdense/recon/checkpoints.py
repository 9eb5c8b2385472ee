"""Load and save reconstruction networks: our format, and the published checkpoints, safely.

Our format is two files side by side:

- ``<name>.pt``: a plain ``state_dict`` (a dict of tensors written by ``torch.save``), which
  ``torch.load(..., weights_only=True)`` reads without running any code;
- ``<name>.json``: ``{"format": "evdense-recon-checkpoint", "version": 1, "arch": ...,
  "hparams": {...}, "provenance": {...}}``.

The published checkpoints (rpg_e2vid's FireNet and E2VID, event_cnn_minimal's FireNet+) are
pickles of a dict holding ``state_dict`` and, for event_cnn_minimal, a pickled
``parse_config.ConfigParser`` object. They are read with torch's weights-only unpickler: only
tensors, plain containers and an allow-list of names load; the foreign config class (and
``pathlib`` paths inside it) are mapped to inert stand-ins that only store their state. Anything
else (``os.system``, ``builtins.eval``, ...) stops the load with a :class:`CheckpointError`
before it is called.

The architecture and its hyper-parameters are read from the checkpoint (the JSON's ``arch``, or
the names and shapes of the state_dict), never from a flag.
"""

from __future__ import annotations

import json
import os
import pickle
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from evdense.log import get_logger
from evdense.recon.networks import NETWORKS, ReconstructionNet, build_network

log = get_logger("recon")

FORMAT_NAME = "evdense-recon-checkpoint"
FORMAT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint that cannot be read safely or does not describe a known network."""


@dataclass
class LoadedCheckpoint:
    """A network with its weights, and where they came from."""

    net: ReconstructionNet
    """The network in eval mode, weights loaded with every key matched."""
    arch: str
    """Architecture name: firenet, firenet_plus or e2vid."""
    hparams: dict[str, Any]
    """Constructor arguments of the network."""
    source_format: str
    """"evdense" (our .pt + .json), "published" (a research checkpoint) or "state_dict"."""
    info: dict[str, Any] = field(default_factory=dict)
    """Provenance: our JSON's provenance, or the published file's arch/epoch/config fields."""


# ---------------------------------------------------------------------------------------------
# Inert stand-ins for the foreign classes found in published checkpoints
# ---------------------------------------------------------------------------------------------


class ForeignObject:
    """Stand-in for a class pickled by research code (e.g. ``parse_config.ConfigParser``).

    It is created without calling any foreign constructor and only keeps the pickled state
    (a dict of plain values) in ``.state``; it has no behaviour.
    """

    def __setstate__(self, state: Any) -> None:
        self.state = state

    def __repr__(self) -> str:
        keys = list(self.state) if isinstance(getattr(self, "state", None), dict) else []
        return f"ForeignObject(keys={keys})"


def _path_parts(*parts: str) -> str:
    """Stand-in for ``pathlib.PosixPath(*parts)`` inside a pickle: the joined string."""
    return str(Path(*[str(p) for p in parts])) if parts else ""


# Names a published checkpoint may reference beyond what the weights-only unpickler allows.
_STAND_INS: list[tuple[Any, str]] = [
    (ForeignObject, "parse_config.ConfigParser"),
    (ForeignObject, "utils.parse_config.ConfigParser"),
    (_path_parts, "pathlib.PosixPath"),
    (_path_parts, "pathlib.WindowsPath"),
    (_path_parts, "pathlib.PurePosixPath"),
    (_path_parts, "pathlib.PureWindowsPath"),
    (_path_parts, "pathlib._local.PosixPath"),
    (_path_parts, "pathlib._local.WindowsPath"),
]


def _unpickling_reason(e: Exception) -> str:
    """The line of torch's weights-only error that names the refused global or operation."""
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    for ln in lines:
        if any(w in ln for w in ("GLOBAL", "global", "reduce", "Can only")):
            return ln
    return lines[0] if lines else repr(e)


MAX_CHECKPOINT_BYTES = 512 << 20
"""Largest checkpoint accepted, unpacked (the largest E2VID checkpoints are about 40 MB)."""


def _check_unpacked_size(path: Path) -> None:
    """Refuse a zip checkpoint that would unpack to more than :data:`MAX_CHECKPOINT_BYTES`
    (torch stores tensors uncompressed; a deflated member is a decompression bomb)."""
    import zipfile

    size = path.stat().st_size
    if not zipfile.is_zipfile(path):
        if size > MAX_CHECKPOINT_BYTES:
            raise CheckpointError(
                f"{path}: {size} bytes, over the {MAX_CHECKPOINT_BYTES >> 20} MiB limit"
            )
        return
    try:
        with zipfile.ZipFile(path) as z:
            total = sum(i.file_size for i in z.infolist())
    except (zipfile.BadZipFile, OSError, ValueError) as e:
        raise CheckpointError(f"{path}: not a readable torch checkpoint ({e})") from None
    if total > MAX_CHECKPOINT_BYTES:
        raise CheckpointError(f"{path}: unpacks to {total} bytes, over the "
                              f"{MAX_CHECKPOINT_BYTES >> 20} MiB limit; refused")  # fmt: skip


def safe_torch_load(path: str | Path) -> Any:
    """``torch.load`` with the weights-only unpickler plus the stand-ins above.

    Raises :class:`CheckpointError` naming the offending global when the pickle references
    anything else (a class or function that could run code when the file is loaded).
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    _check_unpacked_size(path)
    try:
        with torch.serialization.safe_globals(_STAND_INS):
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        first = _unpickling_reason(e)
        raise CheckpointError(
            f"{path}: refused to load this checkpoint: it references code outside the allow-list "
            f"of tensors and plain data ({first}). It may run arbitrary code when unpickled; "
            "it was not executed. Re-save its state_dict with a trusted tool if you trust the file."
        ) from None
    except (RuntimeError, EOFError, OSError, ValueError) as e:
        raise CheckpointError(f"{path}: not a readable torch checkpoint ({e})") from None


# ---------------------------------------------------------------------------------------------
# Architecture from the state_dict
# ---------------------------------------------------------------------------------------------


def _shape(sd: dict[str, torch.Tensor], key: str) -> tuple[int, ...]:
    return tuple(sd[key].shape)


def infer_architecture(sd: dict[str, torch.Tensor]) -> tuple[str, dict[str, Any]]:
    """Architecture name and constructor arguments from the names and shapes of a state_dict."""
    keys = set(sd)
    if "net.head.conv.conv2d.weight" in keys:
        c, b, k, _ = _shape(sd, "net.head.conv.conv2d.weight")
        idx = sorted({int(key.split(".")[2]) for key in keys if key.startswith("net.resblocks.")})
        recurrent = sorted(
            {
                int(key.split(".")[2])
                for key in keys
                if key.startswith("net.resblocks.") and ".recurrent_block." in key
            }
        )
        return "firenet", dict(
            num_bins=b,
            base_channels=c,
            kernel_size=k,
            num_residual_blocks=len(idx),
            recurrent_resblocks=recurrent,
        )
    if "G1.reset_gate.weight" in keys and "head.conv2d.weight" in keys:
        c, b, k, _ = _shape(sd, "head.conv2d.weight")
        return "firenet_plus", dict(num_bins=b, base_channels=c, kernel_size=k)
    if "unetrecurrent.head.conv2d.weight" in keys:
        c, b, k, _ = _shape(sd, "unetrecurrent.head.conv2d.weight")
        enc = {int(key.split(".")[2]) for key in keys if key.startswith("unetrecurrent.encoders.")}
        res = {int(key.split(".")[2]) for key in keys if key.startswith("unetrecurrent.resblocks.")}
        cell = (
            "convlstm"
            if "unetrecurrent.encoders.0.recurrent_block.Gates.weight" in keys
            else "convgru"
        )
        norm = "BN" if "unetrecurrent.encoders.0.conv.norm_layer.weight" in keys else "none"
        if any(".decoders.0.conv2d." in key for key in keys):
            raise CheckpointError(
                "E2VID checkpoint with upsample-convolution decoders (use_upsample_conv=True) "
                "is not supported; only the transposed-convolution (lightweight) decoders are"
            )
        return "e2vid", dict(
            num_bins=b,
            base_channels=c,
            num_encoders=len(enc),
            num_residual_blocks=len(res),
            norm=norm,
            recurrent_block_type=cell,
            kernel_size=k,
        )
    sample = ", ".join(sorted(keys)[:4])
    raise CheckpointError(f"state_dict of no known network (first keys: {sample})")


# ---------------------------------------------------------------------------------------------
# Loading and saving
# ---------------------------------------------------------------------------------------------


def _plain(obj: Any, depth: int = 0) -> Any:
    """JSON-friendly copy of the plain parts of a (published) config, for provenance."""
    if depth > 8:
        return None
    if isinstance(obj, ForeignObject):
        return _plain(getattr(obj, "state", None), depth + 1)
    if isinstance(obj, dict):
        return {str(k): _plain(v, depth + 1) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v, depth + 1) for v in obj]
    if isinstance(obj, str | int | float | bool) or obj is None:
        return obj
    return repr(obj)


def _tidy_state_dict(sd: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Undo two harmless differences of older research checkpoints: the ``module.`` prefix of
    ``nn.DataParallel`` and missing batch-norm ``num_batches_tracked`` counters (torch < 0.4.1)."""
    if sd and all(k.startswith("module.") for k in sd):
        sd = {k[len("module.") :]: v for k, v in sd.items()}
    sd = dict(sd)
    for k in [k for k in sd if k.endswith(".running_mean")]:
        sd.setdefault(k[: -len("running_mean")] + "num_batches_tracked", torch.tensor(0))
    return sd


def _build_and_load(
    path: Path, sd: dict[str, torch.Tensor], arch: str, hparams: dict[str, Any]
) -> ReconstructionNet:
    try:
        net = build_network(arch, **hparams)
    except (TypeError, ValueError) as e:
        raise CheckpointError(f"{path}: cannot build {arch} with {hparams} ({e})") from None
    try:
        net.load_state_dict(sd, strict=True)
    except RuntimeError as e:
        raise CheckpointError(f"{path}: weights do not fit {arch} {hparams}: {e}") from None
    return net.eval()


def load_checkpoint(path: str | Path) -> LoadedCheckpoint:
    """Load a network from our format (``.pt`` + ``.json``), a published checkpoint or a plain state_dict.

    The architecture comes from the JSON when there is one, otherwise from the state_dict's
    names and shapes. All keys must match (``strict=True``). The network is returned on the CPU
    in eval mode.

    Raises:
        CheckpointError: missing or unreadable file, a pickle that references code, or weights
            that fit no known network.
    """
    path = Path(path)
    meta_path = path.with_suffix(".json")
    obj = safe_torch_load(path)
    if not isinstance(obj, dict):
        raise CheckpointError(
            f"{path}: expected a dict in the checkpoint, found {type(obj).__name__}"
        )

    if meta_path.is_file() and all(isinstance(v, torch.Tensor) for v in obj.values()):
        try:
            meta = json.loads(meta_path.read_text())
        except json.JSONDecodeError as e:
            raise CheckpointError(f"{meta_path}: not valid JSON ({e})") from None
        if meta.get("format") != FORMAT_NAME:
            raise CheckpointError(
                f"{meta_path}: format is {meta.get('format')!r}, not {FORMAT_NAME!r}"
            )
        arch = meta.get("arch")
        if arch not in NETWORKS:
            raise CheckpointError(
                f"{meta_path}: unknown arch {arch!r}; known: {', '.join(NETWORKS)}"
            )
        hparams = dict(meta.get("hparams", {}))
        # the weights' own shapes bound what is built: a JSON asking for more is refused before
        # anything is allocated from it
        try:
            arch_sd, hp_sd = infer_architecture(_tidy_state_dict(obj))
        except CheckpointError as e:
            raise CheckpointError(f"{path}: {e}") from None
        wrong = {k: v for k, v in hparams.items() if k in hp_sd and hp_sd[k] != v}
        if arch_sd != arch or wrong:
            raise CheckpointError(
                f"{meta_path}: says {arch} {hparams}, but the weights in {path.name} are "
                f"{arch_sd} {hp_sd}"
            )
        net = _build_and_load(path, obj, arch, hparams)
        return LoadedCheckpoint(net, arch, hparams, "evdense", dict(meta.get("provenance", {})))

    if "state_dict" in obj and isinstance(obj["state_dict"], dict):
        sd = obj["state_dict"]
        fmt = "published"
        info = {k: _plain(obj[k]) for k in ("arch", "epoch", "model", "config") if k in obj}
    elif obj and all(isinstance(v, torch.Tensor) for v in obj.values()):
        sd, fmt, info = obj, "state_dict", {}
    else:
        raise CheckpointError(f"{path}: no state_dict in the checkpoint (keys: {sorted(obj)[:8]})")
    sd = _tidy_state_dict(sd)
    try:
        arch, hparams = infer_architecture(sd)
    except CheckpointError as e:
        raise CheckpointError(f"{path}: {e}") from None
    net = _build_and_load(path, sd, arch, hparams)
    log.info(
        "%s: %s checkpoint, %s %s, %d parameters",
        path.name, fmt, arch, hparams, net.num_parameters(),
    )  # fmt: skip
    return LoadedCheckpoint(net, arch, hparams, fmt, info)


def save_checkpoint(
    net: ReconstructionNet, path: str | Path, provenance: dict[str, Any] | None = None
) -> Path:
    """Write ``net`` in our format: ``path`` (``.pt`` state_dict) and ``path.with_suffix('.json')``.

    Both files are written under temporary names and renamed, the JSON last, so a reader never
    sees a half-written pair. Returns the ``.pt`` path.
    """
    path = Path(path)
    if path.suffix != ".pt":
        raise ValueError(f"{path}: our checkpoints end in .pt (the JSON goes beside it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    sd = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    meta = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "arch": net.arch,
        "hparams": net.hparams(),
        "num_parameters": net.num_parameters(),
        "input_normalization": net.input_normalization,
        "output_range": net.output_range,
        "provenance": provenance or {},
    }
    tmp_pt = path.with_name(path.name + ".partial")
    meta_path = path.with_suffix(".json")
    tmp_json = meta_path.with_name(meta_path.name + ".partial")
    try:
        torch.save(sd, tmp_pt)
        tmp_json.write_text(json.dumps(meta, indent=2, default=str) + "\n")
        os.replace(tmp_pt, path)
        os.replace(tmp_json, meta_path)
    finally:
        tmp_pt.unlink(missing_ok=True)
        tmp_json.unlink(missing_ok=True)
    return path
