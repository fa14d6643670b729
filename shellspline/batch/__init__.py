"""Batch jobs: many keyframe sequences from one TOML file, run in parallel, nothing lost.

A job file (``pipelines/*.toml``) lists sequences — directories found by a glob, explicit
keyframe files, or synthetic keyframes from :mod:`data_synth` — with defaults and
per-sequence overrides of the interpolation parameters. :func:`load_job` validates the whole
file up front; :func:`run_batch` runs every sequence that is not already up to date, on a
local process pool (one process per sequence) or on a Dask distributed cluster (one task
per sequence), and returns a :class:`BatchSummary`.

Guarantees
----------
* Each sequence's output directory ``OUT/<name>/`` appears atomically (everything is written
  into a hidden staging directory ``OUT/.<name>.stage-<hex>`` that is renamed into place) and
  holds ``manifest.json``: sha256 of every input file (or the synthetic generator and its
  parameters), all parameters, the shellspline version, the time and the size of every
  output file.
* Re-running a job skips the sequences whose manifest matches (same inputs, parameters and
  version, every listed output file present with its size) and redoes the others: after a
  Ctrl-C, a crash or a killed worker the job resumes where it stopped. Leftover staging
  directories of a killed run are removed at the start and end of the next run (an output
  root is locked while a job runs on it, so they cannot belong to a live run).
* One failing sequence never stops the others; its one-line reason appears in the summary.
* A task that runs twice (a Dask worker declared dead while still running) does not
  duplicate or tear an output: the second attempt finds a complete output with a matching
  manifest and leaves it untouched.
* SIGINT/SIGTERM stop a run within seconds on either executor: workers stopped, staging
  directories removed, the summary written with exit code 130/143.

Modules: :mod:`~shellspline.batch.schema` (the job file's keys and values),
:mod:`~shellspline.batch.job` (:func:`load_job`, :class:`Job`, :class:`SequenceSpec`),
:mod:`~shellspline.batch.manifest` (input hashes, keys, manifests),
:mod:`~shellspline.batch.sequence` (one sequence in a worker),
:mod:`~shellspline.batch.executors` (local processes, Dask),
:mod:`~shellspline.batch.outroot` (lock, log, leftovers),
:mod:`~shellspline.batch.regression` (expected metrics and their comparison),
:mod:`~shellspline.batch.summary` (:class:`BatchSummary`), :mod:`~shellspline.batch.run`
(:func:`run_batch`: plan → execute → collect → regression → summary).
"""
from .job import Job, SequenceSpec, check_scheduler_address, load_job
from .manifest import MANIFEST_FORMAT
from .outroot import LOCK_NAME, LOG_NAME, SUMMARY_NAME
from .regression import REGRESSION_METRICS, compare_regression, regression_table
from .run import run_batch
from .sequence import sequence_metrics
from .summary import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_JOB, EXIT_OK, BatchSummary

__all__ = ["Job", "SequenceSpec", "BatchSummary", "load_job", "run_batch", "sequence_metrics",
           "REGRESSION_METRICS", "compare_regression", "regression_table",
           "check_scheduler_address", "MANIFEST_FORMAT", "SUMMARY_NAME", "LOG_NAME",
           "LOCK_NAME", "EXIT_OK", "EXIT_FAILED", "EXIT_JOB", "EXIT_INTERRUPTED"]
