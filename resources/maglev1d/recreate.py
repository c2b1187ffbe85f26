"""Re-create the converted recordings of the levitated ball from the original files.

Usage::

    python resources/maglev1d/recreate.py /path/to/levitador-benchmark   # a checkout
    python resources/maglev1d/recreate.py /path/to/levitador-benchmark.git  # or its git directory

Reads the five logs ``data/sesiones_kan_pinn/dataset_*.txt`` of JRavenelco/levitador-benchmark at
commit 2302eb0da3fd31f5c8ab6ac7a37b44792e1d57bf (from the work tree, or with ``git show`` from a
git directory), checks each file's SHA-256 against the values below (and in NOTICE), and writes
``<name>.npz`` (arrays t, y, i, u, yd in SI units, float64, exactly the logged decimal values;
``meta``: where they come from) and ``<name>.json`` (the same meta) next to this script. The
output is byte-for-byte reproducible: running it again on the same originals changes nothing.
Exit status 2 (one line) when a file is missing or its hash differs.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))     # the repository's ssamb, when run from a clone

from ssamb.io import save_npz  # noqa: E402
from ssamb.maglev1d.data import COLUMNS, load_rig_log, sha256_of  # noqa: E402

REPOSITORY = "https://github.com/JRavenelco/levitador-benchmark"
COMMIT = "2302eb0da3fd31f5c8ab6ac7a37b44792e1d57bf"
FOLDER = "data/sesiones_kan_pinn"
#: original file name -> SHA-256 of its bytes at COMMIT
ORIGINALS = {
    "dataset_constante_20251217_205611.txt": "17872354df387ac36d8b3d29adb4d4105e76d0c55332d0aa9bf0006b66b602e9",
    "dataset_escalon_20251217_205858.txt": "d841d6742d4ced1b1b10d674511c47a2a57be2edc6b93e807e1e8f2960517b65",
    "dataset_senoidal_20251217_205952.txt": "eabb28b301558388655d05ee4448916276826be1a3e974a7c8ce59fcf2a558d1",
    "dataset_chirp_20251217_210058.txt": "6e29caf920e99255d2b5f577a19808121f18d494261bf8c012ad6d5f12bb947a",
    "dataset_multiescalon_20251217_210203.txt": "e61b82d9ab577522afd67d21625420154875bae5c6ebe8324938d5f4681af14b",
}
UNITS = {"t": "s", "y": "m", "i": "A", "u": "V", "yd": "m"}


def _fetch(source: Path, name: str, tmp: Path) -> Path:
    """The original file ``name``: from a work tree, or ``git show COMMIT:path`` from a git dir."""
    rel = f"{FOLDER}/{name}"
    if (source / rel).is_file():
        return source / rel
    git_dir = source / ".git" if (source / ".git").exists() else source
    out = tmp / name
    res = subprocess.run(["git", f"--git-dir={git_dir}", "show", f"{COMMIT}:{rel}"], capture_output=True)
    if res.returncode != 0:
        raise SystemExit(f"{source}: {rel} not found (neither a checkout nor a git directory holding {COMMIT[:7]})")
    out.write_bytes(res.stdout)
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__.strip().splitlines()[0], file=sys.stderr)
        print("usage: python resources/maglev1d/recreate.py CHECKOUT_OR_GIT_DIR", file=sys.stderr)
        return 2
    source = Path(argv[0])
    with tempfile.TemporaryDirectory() as td:
        try:
            files = {name: _fetch(source, name, Path(td)) for name in ORIGINALS}
        except SystemExit as exc:
            print(exc, file=sys.stderr)
            return 2
        for name, path in files.items():
            digest = sha256_of(path)
            if digest != ORIGINALS[name]:
                print(f"{path}: sha256 {digest} differs from {ORIGINALS[name]} (not the file of commit {COMMIT[:7]})",
                      file=sys.stderr)
                return 2
        for name, path in files.items():
            arrays, meta = load_rig_log(path)
            meta = {"source_repository": REPOSITORY, "source_commit": COMMIT, "source_file": f"{FOLDER}/{name}",
                    "source_sha256": ORIGINALS[name], "profile": meta.get("profile", ""), "header": meta["header"],
                    "units": UNITS, "fs_hz": 100.0,
                    "changes": "columns y_obs and dy_obs dropped (an observer's placeholders); the other "
                               "columns stored as float64 in SI units, values as logged"}
            out = HERE / (Path(name).stem + ".npz")
            save_npz(out, {c: arrays[c] for c in COLUMNS}, meta=meta, compress=True)
            print(f"{out.name}: {len(arrays['t'])} samples from {name} (sha256 ok)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
