"""``python -m garment_transfer batch``: the command line of ``batch`` (progress bar, log file, exit code)."""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import sys
import time
from pathlib import Path

from ..errors import GarmentTransferError
from ..pipeline import batch as core_batch
from ..pipeline.batch import check_batch_outputs, run_batch
from .options import number_option, share_option
from .paths import batch_catalogue, batch_log

# The core batch's own log: this command sends it to the log file.
log = logging.getLogger(core_batch.__name__)


def add_batch_arguments(p):
    p.description = (
        "Transfer every garment of a catalogue to each of its target bodies. Results go to "
        "OUT/<garment>/<target>.obj with a .json record beside each; OUT/summary.json and summary.csv "
        "list every pair; OUT/batch.log has one line per pair. Re-running skips every pair already done "
        "with the same inputs, settings and code. Exit code: 0 all pairs done, 1 some failed, "
        "130 stopped by Ctrl+C.")
    p.add_argument("catalogue", help="catalogue file (.json or .toml; see docs/batch.md) or dataset "
                                     "folder (bodies/<body>.obj, garments/<garment>/<body>.obj)")
    p.add_argument("--out", required=True, help="results folder")
    p.add_argument("--source", help="dataset folder: the body the garments are dressed on")
    p.add_argument("--targets", help="dataset folder: target bodies, comma-separated (default: every other)")
    p.add_argument("--garments", help="only these garments, comma-separated")
    g = p.add_argument_group("settings (defaults for the garments that do not set them in the catalogue)")
    g.add_argument("--method", choices=["direct", "model", "surface"])
    g.add_argument("--model", help="model file (.npz) for --method model: the paper's shared model or a garment "
                                   "fit model with its learned placement (train --kind garment)")
    g.add_argument("--field-share", type=share_option, default=None, metavar="SHARE",
                   help="garment fit model only: the share of its field, 0 to 1 (default 0.5)")
    g.add_argument("--offset", type=number_option(float, 0.0, what="a distance"),
                   help="distance kept from the body, in the files' units (>= 0)")
    g.add_argument("--no-fix", action="store_true", help="skip the penetration fix")
    g.add_argument("--no-interpolate", action="store_true", help="nearest body triangle only (the paper)")
    g.add_argument("--untangle", action="store_true",
                   help="targets in another rest pose (the catalogue's rig): undo where posing the source folds the "
                        "cloth through itself; seconds more a pair where it does")
    x = p.add_argument_group("where it runs")
    x.add_argument("--workers", type=number_option(int, 1, what="a whole number"), default=None,
                   help="local worker processes (default: every core; 1: in this process)")
    x.add_argument("--dask", action="store_true",
                   help="a local Dask cluster of --workers processes instead of a process pool")
    x.add_argument("--scheduler", metavar="ADDRESS",
                   help="a Dask scheduler (tcp://HOST:8786): run on its workers; they must see the "
                        "catalogue's files and --out at the same paths")
    p.add_argument("--log", help="log file (default: OUT/batch.log; appended to)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--json", action="store_true", help="print the counts and the summary's paths as JSON")
    p.set_defaults(func=batch_main)


class _Bar:
    """A progress bar with ETA on a terminal: tqdm when installed, else one rewritten line."""

    def __init__(self, enabled):
        self.enabled = enabled and sys.stderr.isatty()
        self.tqdm = None
        self.start = time.monotonic()
        self.last = 0.0
        self.failed = 0

    def __call__(self, done, total, record):
        if record is not None and record.get("outcome") == "failed":
            self.failed += 1
        if not self.enabled:
            return False
        if self.tqdm is None:
            try:
                from tqdm import tqdm
            except ImportError:
                self.tqdm = False
            else:
                self.tqdm = tqdm(total=total, unit="pair", dynamic_ncols=True, file=sys.stderr)
        if self.tqdm:
            self.tqdm.n = done
            self.tqdm.set_postfix(failed=self.failed, refresh=False)
            self.tqdm.refresh()
            return False
        now = time.monotonic()
        if now - self.last < 0.5 and done < total:
            return False
        self.last = now
        elapsed = now - self.start
        eta = elapsed / done * (total - done) if done else float("nan")
        eta_text = "?" if eta != eta else time.strftime("%H:%M:%S", time.gmtime(eta))
        print(f"\r{done}/{total} pairs ({100 * done / max(total, 1):.0f}%), {self.failed} failed, "
              f"ETA {eta_text}  ", end="", file=sys.stderr, flush=True)
        return False

    def close(self):
        if self.tqdm:
            self.tqdm.close()
        elif self.enabled and self.tqdm is False:
            print(file=sys.stderr)


def _has_tqdm():
    try:
        import tqdm  # noqa: F401
    except ImportError:
        return False
    return True


def _sigterm(_signum, _frame):
    # A batch system's stop (SIGTERM) ends the run as cleanly as Ctrl+C.
    raise KeyboardInterrupt


def batch_main(args):
    catalogue = batch_catalogue(args)
    if args.workers is not None and args.workers < 1:
        raise GarmentTransferError("--workers must be at least 1")
    # main() checked these before; a direct call gets the same check before anything is made.
    check_batch_outputs(catalogue, args.out, log=batch_log(args))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    handler = logging.FileHandler(batch_log(args), encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
    handler.setLevel(logging.INFO)
    log.addHandler(handler)
    if log.getEffectiveLevel() > logging.INFO:
        log.setLevel(logging.INFO)
    # The terminal shows the bar and failures only; every line goes to the log file.
    for h in logging.getLogger().handlers:
        if h.level == logging.NOTSET and not logging.getLogger().isEnabledFor(logging.INFO):
            h.setLevel(logging.WARNING)
    bar = _Bar(not args.no_progress)
    previous = signal.signal(signal.SIGTERM, _sigterm)
    try:
        redirect = _tqdm_logging() if bar.enabled and _has_tqdm() else None
        if redirect is not None:
            with redirect:
                summary = run_batch(catalogue, out, workers=args.workers, scheduler=args.scheduler,
                                    dask=args.dask, progress=bar)
        else:
            summary = run_batch(catalogue, out, workers=args.workers, scheduler=args.scheduler,
                                dask=args.dask, progress=bar)
    finally:
        signal.signal(signal.SIGTERM, previous)
        bar.close()
        log.removeHandler(handler)
        handler.close()
    c = summary.counts
    result = {"counts": c, "seconds": summary.seconds, "interrupted": summary.interrupted,
              "summary": str(out / "summary.json"), "csv": str(out / "summary.csv"), **summary.info}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"{c['done']} done, {c['skipped']} already done, {c['failed']} failed, {c['not run']} not run "
              f"in {summary.seconds:.1f} s{' (interrupted)' if summary.interrupted else ''}; "
              f"summary in {out / 'summary.json'} and summary.csv")
    if summary.interrupted:
        return 130
    return 0 if summary.ok else 1


class _AboveBar(logging.Handler):
    """Log lines printed above the progress bar instead of through it."""

    def __init__(self, original):
        super().__init__(original.level)
        self.setFormatter(original.formatter)

    def emit(self, record):
        try:
            from tqdm import tqdm

            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must not stop the run
            self.handleError(record)


@contextlib.contextmanager
def _tqdm_logging():
    root = logging.getLogger()
    swapped = [(h, _AboveBar(h)) for h in root.handlers
               if type(h) is logging.StreamHandler and h.stream in (sys.stderr, sys.stdout)]
    for old, new in swapped:
        root.removeHandler(old)
        root.addHandler(new)
    try:
        yield
    finally:
        for old, new in swapped:
            root.removeHandler(new)
            root.addHandler(old)
