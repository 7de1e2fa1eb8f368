"""Many lockstep runs at once, for the studies' reproductions: a function over a list of jobs on worker
processes (or in this process), in order, with a progress bar; and the options every reproduction has.

A campaign file's points go through hil.campaign.sweep (cached, resumable, local or Dask); a
reproduction's runs are a fixed list that it reduces itself, so they only need this.  `executor_map`
runs such a list on any executor a campaign runs on (hil.campaign.sweep.executor_for: this process,
local processes or a Dask cluster): the threat matrix's cells go that way.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import TypeVar

from hil.errors import RailhilError
from hil.progress import progress_bar

J = TypeVar("J")
R = TypeVar("R")


def map_jobs(fn: Callable[[J], R], jobs: Iterable[J], workers: int, desc: str,
             progress: bool = True) -> list[R]:
    """`fn(job)` for every job, results in job order: in this process when `workers` <= 1, else on that
    many worker processes (one job at a time each: runs differ much in length); a progress bar on stderr
    when `progress` and stderr is a terminal."""
    jobs = list(jobs)
    bar = progress_bar(len(jobs), enabled=progress, desc=desc, unit="run")
    results: list[R] = []
    try:
        if workers <= 1:
            for job in jobs:
                results.append(fn(job))
                bar.update()
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                for res in pool.map(fn, jobs, chunksize=1):
                    results.append(res)
                    bar.update()
    finally:
        bar.close()
    return results


def executor_map(fn: Callable[..., R], jobs: Sequence[tuple], executor: Executor | None,
                 done: Callable[[R], None] | None = None,
                 failed: Callable[[tuple, BaseException], R] | None = None) -> list[R]:
    """`fn(*job)` for every job, results in job order: in this process, one after the other, when
    `executor` is None; else all submitted to `executor` at once (local processes, a Dask cluster's
    executor), so `fn` and the jobs must pickle.  `done(result)` is called as each finishes (completion
    order).  A job whose future raised (a worker died, a lost connection) gives `failed(job, exc)`; without
    `failed` that exception propagates.  Ctrl-C cancels the jobs not started and propagates."""
    results: dict[int, R] = {}
    if executor is None:
        for i, job in enumerate(jobs):
            results[i] = fn(*job)
            if done is not None:
                done(results[i])
        return [results[i] for i in range(len(jobs))]
    futures: dict[Future, int] = {executor.submit(fn, *job): i for i, job in enumerate(jobs)}
    try:
        for fut in as_completed(futures):
            i = futures[fut]
            try:
                results[i] = fut.result()
            except Exception as exc:
                if failed is None:
                    raise
                results[i] = failed(jobs[i], exc)
            if done is not None:
                done(results[i])
    finally:
        for fut in futures:
            fut.cancel()
    return [results[i] for i in range(len(jobs))]


def add_executor_options(p: argparse.ArgumentParser, what: str, jobs: int, dask_note: str = "") -> None:
    """-j/--jobs or --dask, and --dask-timeout: where `what` (points, cells, runs) run
    (hil.campaign.sweep.executor_for); `jobs` the default worker count; `dask_note` added to --dask's help."""
    where = p.add_mutually_exclusive_group()
    default = "the number of CPUs; 1 = in this process" if jobs > 1 else "1, in this process"
    where.add_argument("-j", "--jobs", type=int, default=jobs, metavar="N",
                       help=f"local worker processes running {what} in parallel (default: {default})")
    where.add_argument("--dask", metavar="ADDRESS", default=None,
                       help=f"run the {what} on the Dask distributed cluster whose scheduler is at ADDRESS, "
                            f"e.g. tcp://host:8786 (needs the dask extra{dask_note})")
    p.add_argument("--dask-timeout", type=float, default=10.0, metavar="S",
                   help="seconds to wait for the Dask scheduler to answer (default 10)")


def check_executor_options(args: argparse.Namespace, error: type[RailhilError]) -> None:
    """--jobs at least 1 and --dask-timeout positive: else one line naming the option (`error` for the
    timeout, the campaign's error for --jobs, as hil.campaign.sweep.check_positive)."""
    # lazy: the campaign runner (1 s to import) stays out of `railhil wsp-test --help` (50 ms)
    from hil.campaign.sweep import check_positive

    check_positive("--jobs", args.jobs)
    if args.dask_timeout <= 0:
        raise error(f"--dask-timeout {args.dask_timeout}: expected a positive number of seconds")


def add_run_options(p: argparse.ArgumentParser, out: str, what: str, jobs: int = 2) -> None:
    """--jobs, --out and -q, as every reproduction has them."""
    p.add_argument("--jobs", type=int, default=jobs,
                   help=f"worker processes for the runs (default {jobs}; 1 = in this process)")
    p.add_argument("--out", type=Path, default=Path("runs") / out,
                   help=f"folder for {what} (default runs/{out})")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def checked_out(args: argparse.Namespace, error: type[RailhilError]) -> Path:
    """--jobs at least 1 and --out a folder (created): else one `error` line naming the option."""
    if args.jobs < 1:
        raise error(f"--jobs {args.jobs}: expected a number of worker processes >= 1")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise error(f"--out {out}: exists and is not a folder; expected a folder for the runs and figures")
    out.mkdir(parents=True, exist_ok=True)
    return out
