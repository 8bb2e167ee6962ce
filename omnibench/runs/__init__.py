"""Run directories: writer (flushed as it goes), reader (pandas), importers.

Public interface::

    from omnibench.runs import RunWriter, read_run, find_runs, SAMPLE_COLUMNS

See docs/run-format.md for the format.
"""

from omnibench.runs.store import (
    FORMAT,
    FORMAT_VERSION,
    SAMPLE_COLUMNS,
    Run,
    RunWriter,
    find_runs,
    is_run_dir,
    read_run,
    run_dirs,
)

__all__ = ["FORMAT", "FORMAT_VERSION", "SAMPLE_COLUMNS", "Run", "RunWriter", "find_runs", "is_run_dir", "read_run",
           "run_dirs"]
