"""What reproduces a run, for its run.json: the versions of railhil and the libraries that matter, the seed,
the DBC and its SHA-256, the git commit of railhil's source, the command line.

The git commit is read from the repository's .git directory (HEAD, loose refs, packed-refs), so no git
program is run.
"""

from __future__ import annotations

import hashlib
import platform
import sys
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from hil import build

#: distributions whose versions go into run.json (and the report): what a reproduction needs to match
VERSIONED = ("railhil", "python-can", "cantools", "numpy", "pydantic", "matplotlib")


def _repo_root(start: Path) -> Path | None:
    for folder in (start, *start.parents):
        if (folder / ".git").exists():
            return folder
    return None


def git_commit(start: Path | None = None) -> str | None:
    """The commit checked out in the git repository holding `start` (default: railhil's own source), as
    40 hex digits; None outside a repository or when .git cannot be read. Reads .git's files only."""
    root = _repo_root((start or Path(__file__)).resolve().parent)
    if root is None:
        return None
    git = root / ".git"
    try:
        if git.is_file():                              # a worktree or submodule: "gitdir: <path>"
            git = (root / git.read_text().split(":", 1)[1].strip()).resolve()
        head = (git / "HEAD").read_text().strip()
        if not head.startswith("ref:"):
            return head or None                        # detached HEAD: the commit itself
        ref = head.split(":", 1)[1].strip()
        common = git / "commondir"
        base = (git / common.read_text().strip()).resolve() if common.exists() else git
        for folder in (git, base):
            loose = folder / ref
            if loose.is_file():
                return loose.read_text().strip() or None
        packed = base / "packed-refs"
        if packed.is_file():
            for line in packed.read_text().splitlines():
                parts = line.split()
                if len(parts) == 2 and parts[1] == ref:
                    return parts[0]
    except (OSError, IndexError, UnicodeDecodeError):
        return None
    return None


@cache
def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for dist in VERSIONED:
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "not installed"
    return out


def sha256_of(path: Path) -> str | None:
    """SHA-256 (hex) of a file's bytes; None when it cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def run_metadata(dbc_path: Path, seed: int) -> dict:
    """What reproduces a run, for run.json: versions, seed, the DBC and its SHA-256, the git commit of
    railhil's source, the command line that started the process, and the build that ran it (compiled by
    mypyc or pure Python: hil.build)."""
    return {"versions": dict(_versions()), "build": build.state().as_dict(), "seed": seed,
            "dbc_sha256": sha256_of(dbc_path),
            "git_commit": git_commit(), "command": " ".join(sys.argv), "platform": platform.platform()}
