"""sha256 of a run folder's result files: what a refactor, a resume or a fault must leave
byte-identical (the tests' and benchmarks/fault_matrix.py's; benchmarks/gpu_hybrid_check.py keeps its
one short id over all metric files, the form its recorded results are written in)."""

from __future__ import annotations

from hashlib import sha256
from pathlib import Path

RESULT_FILES = ("records.parquet", "metrics/BenchmarkMetrics.csv")


def result_digests(folder: Path, files: tuple[str, ...] = RESULT_FILES) -> tuple[str, ...] | None:
    """Each of `files`' sha256 under `folder`, in order; None where one is missing (a run that did not
    finish)."""
    if not all((folder / f).is_file() for f in files):
        return None
    return tuple(sha256((folder / f).read_bytes()).hexdigest() for f in files)
