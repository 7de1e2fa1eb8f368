"""Many lockstep runs at once, for the studies' reproductions: a function over a list of jobs on worker
processes (or in this process), in order, with a progress bar; and the options every reproduction has.

A campaign file's points go through hil.campaign.sweep (cached, resumable, local or Dask); a
reproduction's runs are a fixed list that it reduces itself, so they only need this.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import TypeVar

from hil.errors import RailhilError

J = TypeVar("J")
R = TypeVar("R")


def map_jobs(fn: Callable[[J], R], jobs: Iterable[J], workers: int, desc: str,
             progress: bool = True) -> list[R]:
    """`fn(job)` for every job, results in job order: in this process when `workers` <= 1, else on that
    many worker processes (one job at a time each: runs differ much in length); a tqdm bar on stderr."""
    from tqdm import tqdm

    jobs = list(jobs)
    bar = tqdm(total=len(jobs), desc=desc, unit="run", disable=not progress, file=sys.stderr)
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
