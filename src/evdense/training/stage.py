"""The training stage (``evdense train RUN_DIR`` or ``python -m evdense.training RUN_DIR``): our
reconstruction weights from our simulator's data, in one resumable run folder.

``RUN_DIR`` holds the simulated set ``trainset_s<seed>.h5`` (:mod:`evdense.training.data`) and
one ``trainset_s<seed>_mix<i>.h5`` per further recipe of ``train.mix``, the
checkpoints and ``history.jsonl`` of the loop (:mod:`evdense.training.train`) and, by default, the
best weights ``evfirenet.pt`` with their JSON, which records the recipe, the validation result and
the held-out scores (:mod:`evdense.training.heldout`). The settings are the config's ``train``
section.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from evdense.log import get_logger
from evdense.training.data import TrainDataConfig
from evdense.training.train import TrainConfig, TrainResult, train_model, update_provenance

log = get_logger("training")


def run_training(
    conf: TrainConfig,
    run_dir: str | Path,
    weights_path: str | Path | None = None,
    workers: int = 1,
    resume: bool = True,
    evaluate: bool = True,
) -> TrainResult:
    """The whole recipe: simulate the data set (unless cached), train, score on held-out sequences.

    ``run_dir`` holds ``trainset_s<seed>.h5`` and the ``train.mix`` sets
    ``trainset_s<seed>_mix<i>.h5`` (each reused when present), ``checkpoints/`` and
    ``history.jsonl``; the best weights go to ``weights_path`` (default
    ``run_dir/evfirenet.pt``), whose JSON gets the held-out SSIM/MSE of the weights when
    ``evaluate``. ``workers``: processes simulating the data.
    """
    from evdense.training.heldout import EvalConfig, evaluate_methods

    run_dir = Path(run_dir)
    weights_path = Path(weights_path) if weights_path else run_dir / "evfirenet.pt"
    data_path = run_dir / f"trainset_s{conf.seed}.h5"
    extra: dict[str, Any] = {}
    seconds = _simulate_or_reuse(data_path, conf.data, conf.splits(), conf.seed, workers)
    if seconds is not None:
        extra["data_seconds"] = seconds
    mix_paths = []
    for i, mix in enumerate(conf.mix_recipes()):
        path = run_dir / f"trainset_s{conf.seed}_mix{i}.h5"
        splits = {"train": mix.num_train_sequences, "val": 0, "heldout": 0}
        seconds = _simulate_or_reuse(path, mix.recipe, splits, mix.seed, workers)
        if seconds is not None:
            extra[f"data_seconds_mix{i}"] = seconds
        mix_paths.append(path)
    result = train_model(conf, data_path, run_dir, weights_path, resume=resume, mix_paths=mix_paths)
    extra["final_step"] = result.step
    extra["best_step"] = result.best_step
    extra["total_train_seconds"] = result.train_seconds
    if evaluate and weights_path.is_file():
        rows = evaluate_methods(data_path, {"ours": str(weights_path)}, EvalConfig())
        extra["heldout_metrics"] = rows[0]
    if weights_path.is_file():
        update_provenance(weights_path, extra)
    return result


def _simulate_or_reuse(
    path: Path, recipe: TrainDataConfig, splits: dict[str, int], seed: int, workers: int
) -> float | None:
    """Simulate the set ``path`` unless it exists; the seconds spent, or None when reused.

    A reused set made with another recipe, seed or number of sequences (of the splits asked for)
    is kept, since it may be a copy made on purpose, with a warning that names what differs.
    """
    from evdense.training.data import generate_dataset, read_config, read_seed, read_splits

    if path.is_file():
        had, want = _plain(asdict(read_config(path))), _plain(asdict(recipe))
        differ = sorted(k for k in want if had.get(k) != want[k])
        had_seed = read_seed(path)
        if had_seed != seed:
            differ.append(f"seed ({had_seed}, not {seed})")
        made = read_splits(path)
        differ += [f"{k} sequences ({made.get(k, 0)}, not {n})"
                   for k, n in splits.items() if n and made.get(k, 0) != n]  # fmt: skip
        if differ:
            log.warning("%s: reused, made with other %s than the config (delete it to simulate "
                        "it again)", path, ", ".join(differ))  # fmt: skip
        return None
    t0 = time.monotonic()
    generate_dataset(path, recipe, splits, seed=seed, workers=workers)
    return time.monotonic() - t0


def _plain(x: Any) -> Any:
    """``x`` as JSON would give it back: tuples as lists (dicts compare without their order)."""
    return json.loads(json.dumps(x))
