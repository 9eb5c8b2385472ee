"""Run the evdense workflow (the repository's ``Snakefile``) from Python, through Snakemake's API.

:func:`run_workflow` is what ``snakemake --cores N --configfile CFG --directory OUT`` does on the
command line, in this process: Snakemake's own progress lines (jobs planned, started, finished,
"N of M steps done") go to the terminal as usual, and the rule scripts run as their own
processes. It returns whether every job succeeded; a failed job leaves what it made marked
incomplete, and the next call resumes from there (Snakemake's bookkeeping in ``OUT/.snakemake``).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from evdense.config import REPO_ROOT
from evdense.log import get_logger

log = get_logger("workflow")

SNAKEFILE = REPO_ROOT / "Snakefile"


def run_workflow(
    configfile: str | Path,
    workdir: str | Path,
    cores: int = 2,
    dry_run: bool = False,
    set_threads: Mapping[str, int] | None = None,
    targets: tuple[str, ...] = (),
) -> bool:
    """Run (or with ``dry_run`` only plan) the workflow on ``configfile`` in ``workdir``.

    ``set_threads``: rule name -> threads (as ``--set-threads``; ``{"run_sfm": 1}`` makes SfM
    reproducible); ``targets``: files or rules to make (default: the ``all`` rule). ``True`` when
    every job succeeded (or, dry, when the plan was made).
    """
    from snakemake.api import SnakemakeApi
    from snakemake.exceptions import WorkflowError
    from snakemake.settings.types import (
        ConfigSettings,
        DAGSettings,
        ExecutionSettings,
        OutputSettings,
        ResourceSettings,
    )

    configfile, workdir = Path(configfile).resolve(), Path(workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    cwd = os.getcwd()  # Snakemake changes into the working directory; give the caller theirs back
    log.info("workflow: %s on %s in %s (%d cores%s)", SNAKEFILE, configfile, workdir, cores,
             ", dry run" if dry_run else "")  # fmt: skip
    try:
        with SnakemakeApi(OutputSettings(dryrun=dry_run, printshellcmds=True)) as api:
            wf = api.workflow(
                resource_settings=ResourceSettings(
                    cores=cores, overwrite_threads=dict(set_threads or {})
                ),
                config_settings=ConfigSettings(configfiles=[configfile]),
                snakefile=SNAKEFILE,
                workdir=workdir,
            )
            dag = wf.dag(DAGSettings(targets=frozenset(targets)))
            dag.execute_workflow(
                executor="dryrun" if dry_run else "local",
                execution_settings=ExecutionSettings(keep_going=True),
            )
    except WorkflowError as e:
        log.error("workflow failed: %s", e)
        return False
    finally:
        os.chdir(cwd)
    return True
