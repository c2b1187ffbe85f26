"""Provenance: which code and which packages made a result.

:func:`source_revision` names the code: the git commit of the checkout ssamb runs from (marked
when it has uncommitted changes), or, for an installed copy or an unpacked archive with no git
history, the SHA-256 of its source files. :func:`versions` lists the interpreter and every
package ssamb depends on (:data:`DEPENDENCIES`, the ``dependencies`` of ``pyproject.toml``), read
from the installed distributions' metadata, so that no entry is left unknown.
"""
from __future__ import annotations

import hashlib
import platform
import subprocess
from importlib import metadata
from pathlib import Path

__all__ = ["DEPENDENCIES", "versions", "source_revision", "source_hash"]

#: the distributions ssamb depends on, as ``pyproject.toml`` names them (a test keeps them equal)
DEPENDENCIES = ("numpy", "scipy", "control", "sippy-unipi", "snakemake", "matplotlib", "nbconvert", "nbformat",
                "ipykernel", "numba", "pyyaml", "jsonschema", "tqdm", "threadpoolctl")

PACKAGE_DIR = Path(__file__).resolve().parent


def versions() -> dict:
    """The Python version and the installed version of every dependency.

    Returns
    -------
    dict
        ``{"python": "3.x.y", "numpy": ..., "sippy_unipi": ..., ...}``: keys are the
        distribution names with ``-`` written ``_``; a distribution that is not installed
        maps to None (ssamb cannot run without it, so this only happens in a broken
        environment).
    """
    out = {"python": platform.python_version()}
    for dist in DEPENDENCIES:
        try:
            out[dist.replace("-", "_")] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist.replace("-", "_")] = None
    return out


def _git(*args: str, cwd: Path) -> str | None:
    try:
        r = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def source_hash(root: str | Path = PACKAGE_DIR) -> str:
    """SHA-256 over the relative paths and bytes of every file under ``root`` (sorted; compiled
    ``__pycache__`` files left out): the identity of an installed copy of the sources."""
    root = Path(root)
    h = hashlib.sha256()
    for f in sorted(p for p in root.rglob("*") if p.is_file() and "__pycache__" not in p.parts):
        h.update(str(f.relative_to(root).as_posix()).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()


def source_revision(root: str | Path | None = None) -> str:
    """The code that runs: ``git <commit>`` (with ``+ uncommitted changes`` when the tracked files
    differ from it), or ``sha256 <hash> of the ssamb sources (no git checkout)``.

    Parameters
    ----------
    root : path, optional
        Where to look for the git checkout; by default the folder that holds the ``ssamb``
        package.

    Returns
    -------
    str
        A one-line identification of the source code.
    """
    root = Path(root) if root is not None else PACKAGE_DIR.parent
    top = _git("rev-parse", "--show-toplevel", cwd=root)
    if top and (Path(top) / "ssamb").resolve() == PACKAGE_DIR:
        commit = _git("rev-parse", "HEAD", cwd=root)
        if commit:
            dirty = _git("status", "--porcelain", "--untracked-files=no", cwd=root)
            return f"git {commit}" + (" + uncommitted changes" if dirty else "")
    return f"sha256 {source_hash()} of the ssamb sources (no git checkout)"
