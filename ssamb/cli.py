"""Command line: ``python -m ssamb <command> ...``.

Commands (a stable interface; docs/cli.md):

* ``simulate --experiment NAME [--config FILE] [--set KEY=VALUE ...] --out FILE.npz``
* ``rig SCENARIO.yaml --out FILE.npz``
* ``closeloop DATA [DATA ...] [--hold DATA ...] --out DIR [--device NAME] [--config FILE] [--workers N]``
  (``NAME``: ``amb``, the default, or ``maglev1d``; DATA in a format of that device). One file:
  the analysis of that recording (its own split into fitting and held-out parts); several, or any
  ``--hold``: calibrate on the DATA recordings, judge on the ``--hold`` ones
  (:mod:`ssamb.closeloop.recordings`)

Every command exits with status 2 and a one-line reason on bad input (an
:class:`ssamb.errors.InputError`: a config, scenario, effect or data-file error), and writes no
partial file (all writers are atomic). Where the outputs go is checked before any work (a folder
that cannot be written, a path under a file, an output that is a folder); an existing output
(a ``.json`` sidecar included) is overwritten only with ``--force``. Any other exception is a
programming error and keeps its traceback.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2
        sys.stderr.write(f"ssamb: error: {message}\n")
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="python -m ssamb", description="ssamb: mu-analysis of a self-sensing AMB, reproduced")
    sub = ap.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("simulate", help="run the nonlinear simulator for an experiment named in the config")
    p.add_argument("--experiment", required=True, help="experiment name (config 'experiments')")
    p.add_argument("--config", default=None, help="config file (default: ./config.yaml if there is one, else the "
                                                  "configuration shipped with ssamb)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config value, dotted key (repeatable)")
    p.add_argument("--out", required=True, help="output .npz (a .json sidecar is written beside it)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output (and its .json sidecar)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("rig", help="simulate a rig (nominal model + effects + noise) from a scenario file")
    p.add_argument("scenario", help="scenario YAML")
    p.add_argument("--out", required=True, help="output .npz in the measured-data format")
    p.add_argument("--force", action="store_true", help="overwrite an existing output (and its .json sidecar)")
    p.add_argument("--quiet", action="store_true")

    p = sub.add_parser("closeloop", help="find what the model lacks from measured data")
    p.add_argument("data", nargs="+", help="measured data (amb: .npz, or .csv with a .json sidecar; maglev1d: a CSV "
                                           "with columns t,y,i,u,yd, the rig's text log, or the converted .npz)")
    p.add_argument("--hold", action="append", default=[], metavar="DATA",
                   help="a held-out recording: calibrate on DATA, report the errors on these (repeatable)")
    p.add_argument("--out", required=True, help="output directory (closeloop.json and figures)")
    p.add_argument("--device", default="amb", help="the device the data come from: amb (default) or maglev1d")
    p.add_argument("--config", default=None, help="config of the nominal model (default: the device's own)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes for the independent replays (default: the CPUs available; the result does not "
                        "depend on it)")
    p.add_argument("--force", action="store_true", help="replace a previous analysis in --out")
    p.add_argument("--quiet", action="store_true")
    return ap


def _cmd_simulate(args) -> None:
    from .config import load_config
    from .errors import InputError
    from .sim import simulate

    from .io import check_output_file

    out = Path(args.out)
    if out.suffix != ".npz":
        raise InputError(f"--out {out}: must end in .npz")
    check_output_file(out, force=args.force)
    cfg = load_config(args.config, args.overrides)
    if args.experiment not in cfg["experiments"]:
        raise InputError(f"--experiment {args.experiment}: not in config (known: {', '.join(cfg['experiments'])})")
    res = simulate(cfg, args.experiment, progress=None if not args.quiet else False)
    res.save(out)


def _cmd_rig(args) -> None:
    from .rig import run_scenario

    run_scenario(args.scenario, args.out, progress=not args.quiet, force=args.force)


def _cpus() -> int:
    """CPUs this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _cmd_closeloop(args) -> None:
    from .closeloop import run_closeloop
    from .closeloop.report import findings_text

    from .errors import InputError

    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be at least 1")
    workers = args.workers or _cpus()
    from .device import get_device
    from .stages import check_closeloop_settings

    dev = get_device(args.device)
    cfg = dev.load_config(args.config)
    check_closeloop_settings(cfg, dev, source=args.config or f"the default config of device '{dev.name}'")
    if len(args.data) == 1 and not args.hold:
        rep = run_closeloop(args.data[0], args.out, config=cfg, progress=not args.quiet, workers=workers,
                            device=dev, force=args.force)
    else:
        from .closeloop.recordings import run_recordings

        rep = run_recordings(args.data, args.hold, args.out, config=cfg, device=dev,
                             progress=not args.quiet, workers=workers, force=args.force)
    print("\n".join(findings_text(rep) + [f"note: {n}" for n in rep.get("notes", [])]))


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (0 success, 2 bad input)."""
    from ._threads import pin_blas_threads
    from .errors import InputError

    args = _parser().parse_args(argv)
    pin_blas_threads()
    handlers = {"simulate": _cmd_simulate, "rig": _cmd_rig, "closeloop": _cmd_closeloop}
    try:
        handlers[args.command](args)
    except InputError as exc:
        msg = " ".join(str(exc).split())
        sys.stderr.write(f"ssamb {args.command}: error: {msg}\n")
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
