"""The training stage (``evdense train RUN_DIR`` or ``python -m evdense.training RUN_DIR``): our
reconstruction weights from our simulator's data, in one resumable run folder.

``RUN_DIR`` holds the simulated set ``trainset_s<seed>.h5`` (:mod:`evdense.training.data`), the
checkpoints and ``history.jsonl`` of the loop (:mod:`evdense.training.train`) and, by default, the
best weights ``evfirenet.pt`` with their JSON, which records the recipe, the validation result and
the held-out scores (:mod:`evdense.training.heldout`). The settings are the config's ``train``
section.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from evdense.training.train import TrainConfig, TrainResult, train_model, update_provenance


def run_training(
    conf: TrainConfig,
    run_dir: str | Path,
    weights_path: str | Path | None = None,
    workers: int = 1,
    resume: bool = True,
    evaluate: bool = True,
) -> TrainResult:
    """The whole recipe: simulate the data set (unless cached), train, score on held-out sequences.

    ``run_dir`` holds ``trainset_s<seed>.h5`` (reused when present), ``checkpoints/`` and
    ``history.jsonl``; the best weights go to ``weights_path`` (default
    ``run_dir/evfirenet.pt``), whose JSON gets the held-out SSIM/MSE of the weights when
    ``evaluate``. ``workers``: processes simulating the data.
    """
    from evdense.training.data import generate_dataset
    from evdense.training.heldout import EvalConfig, evaluate_methods

    run_dir = Path(run_dir)
    weights_path = Path(weights_path) if weights_path else run_dir / "evfirenet.pt"
    data_path = run_dir / f"trainset_s{conf.seed}.h5"
    extra: dict[str, Any] = {}
    if not data_path.is_file():
        t0 = time.monotonic()
        generate_dataset(data_path, conf.data, conf.splits(), seed=conf.seed, workers=workers)
        extra["data_seconds"] = time.monotonic() - t0
    result = train_model(conf, data_path, run_dir, weights_path, resume=resume)
    extra["final_step"] = result.step
    extra["best_step"] = result.best_step
    extra["total_train_seconds"] = result.train_seconds
    if evaluate and weights_path.is_file():
        rows = evaluate_methods(data_path, {"ours": str(weights_path)}, EvalConfig())
        extra["heldout_metrics"] = rows[0]
    if weights_path.is_file():
        update_provenance(weights_path, extra)
    return result
