"""A whole catalogue: every garment on every target body, resumable, on one machine or a Dask cluster.

A *catalogue* (``catalogue``: its reading and checks) lists garments, each dressed on a source body, the
target bodies to transfer it to, and the method and settings.

The unit of work is one garment with all its targets (``run_garment``): the garment is read and
prepared (binding, Poisson factor) once and reused for every target. Each result is written by the
worker that made it, next to its record::

    <out>/<garment>/<target>.obj     the garment on the target body (the garment file's own faces)
    <out>/<garment>/<target>.json    settings, the key, metrics, seconds, where it was computed

Both are written whole or not at all (a temporary file, then a rename; the ``.json`` last, so a
result counts only once both are there). The key is a SHA-256 of the input files' bytes, the settings
and the code version: a re-run skips every pair whose record holds the same key and whose ``.obj``
is intact, so an interrupted or partly failed run is resumed by running it again.

The driver (``run_batch``) sends garments to an executor, collects the records, and writes
``summary.json`` and ``summary.csv`` (one row per pair, catalogue order). The executors share that
code path: in this process (``workers=1``), a local process pool, a local Dask cluster, or a Dask
scheduler's cluster (``scheduler="tcp://host:8786"``). Dask is imported only here, when asked for.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import logging
import math
import os
import socket
import threading
import time
import uuid
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..errors import GarmentTransferError
from ..files import check_outputs
from ..geometry.proximity import as_same_mesh
from ..geometry.obj import obj_text, read_obj
from ..learning.model_files import read_model_file
from ..rigging.posing import Rig
from ..rigging.naming import read_target_frames, read_target_skeleton
from ..rigging.skeleton import read_joints, read_skeleton
from ..rigging.skinning import read_weights
from ..version import __version__
from .catalogue import Catalogue, GarmentJob, RigFiles, Settings, Target
from .any_body import registration_for, transfer_to_any_body
from .metrics import evaluate
from .pose_fit import posed_counts
from .rest_pose import fold_warnings, target_at_rest, transfer_across_rest_poses
from .result_check import result_warnings
from .transfer import prepare_garment

log = logging.getLogger(__name__)

CSV_COLUMNS = ("garment", "target", "label", "outcome", "seconds", "prepare_seconds", "mdc",
               "penetration_ratio", "max_penetration_depth", "penetrating_vertices", "drape_reference",
               "drape_error", "drape_error_relative", "vertex_error_mean", "vertex_error_max", "registered",
               "output", "worker", "error")
METRIC_KEYS = ("vertices", "triangles", "mdc", "penetration_ratio", "max_penetration_depth",
               "penetrating_vertices", "drape_reference", "drape_error", "drape_error_source",
               "drape_error_relative", "vertex_error_mean", "vertex_error_max")
#: The figures of the promise a record keeps (``result_check.check_result``'s, of the file as written).
CHECK_KEYS = ("garment_edges_through_body", "body_edges_through_garment", "garment_edge_body_pairs",
              "body_edge_garment_pairs", "inside_vertices", "self_intersections", "self_intersections_source",
              "self_intersections_new", "min_body_distance", "seam_vertices", "seam_gap")
#: Outcomes of a pair: transferred now, found from an earlier run, failed, or not reached.
OUTCOMES = ("done", "skipped", "failed", "not run")
PARTIAL_PREFIX = ".partial-"
#: The package's modules (paths in it, without ``.py``; a folder for all of it) that cannot change a result's
#: vertices or metrics: the command line, this module's bookkeeping, the reading of catalogues (the settings it
#: reads are in the key themselves), training, the packages' faces. A change to any other module makes every
#: earlier result stale, a module added later included.
NOT_RESULT_MODULES = frozenset({"__init__", "__main__", "version", "files", "cli", "pipeline/batch",
                                "pipeline/catalogue", "learning/training", "learning/garment_training"})


def result_modules() -> list:
    """The package's modules whose code decides a result (hashed by ``code_version``), as dotted names in the
    package (``geometry.mesh``)."""
    root = Path(__file__).resolve().parents[1]
    out = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).with_suffix("").as_posix()
        if path.name == "__init__.py" or rel in NOT_RESULT_MODULES or rel.split("/")[0] in NOT_RESULT_MODULES:
            continue
        out.append(rel.replace("/", "."))
    return out


class MissingDependency(GarmentTransferError):
    """An optional package that the asked-for executor needs is not installed."""


# ----------------------------------------------------------------------------------------------
# What a run reads and writes


def batch_paths(catalogue: Catalogue, out, log=None) -> dict:
    """What a run of ``catalogue`` into ``out`` reads and writes, as ``files.check_outputs``'s arguments.

    ``out`` must be no input, lie in no input folder and hold no input (its sub-folders are named by the
    catalogue's garments: a garment named ``bodies`` must not land on a dataset's bodies), and no result,
    record, summary or the log (``log``, appended to) may be an input.
    """
    files, folders = catalogue.inputs()
    out = Path(os.fspath(out))
    outputs = [p for g, t in catalogue.pairs() for p in result_paths(out, g, t)]
    outputs += [out / "summary.json", out / "summary.csv"] + ([] if log is None else [(log, "--log")])
    return dict(files=outputs, folders=[out], inputs=files, input_folders=folders, holds_none=True)


def check_batch_outputs(catalogue: Catalogue, out, log=None):
    """Raise ``files.OutputError`` unless a run of ``catalogue`` into ``out`` harms none of its inputs
    (``batch_paths``); checked before any work by ``run_batch`` and the command."""
    check_outputs(**batch_paths(catalogue, out, log))


# ----------------------------------------------------------------------------------------------
# Keys and files


def code_version() -> str:
    """The package version and a hash of the modules that compute results."""
    global _CODE_VERSION
    if _CODE_VERSION is None:
        h = hashlib.sha256()
        root = Path(__file__).resolve().parents[1]
        for m in result_modules():
            h.update(m.encode())
            h.update(root.joinpath(*m.split(".")).with_suffix(".py").read_bytes())
        _CODE_VERSION = f"{__version__}+{h.hexdigest()[:12]}"
    return _CODE_VERSION


_CODE_VERSION = None


def file_digest(path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def pair_key(settings: Settings, target: Target, digests: dict) -> str:
    """The key of one pair's result: inputs' SHA-256, settings, label and code version."""
    blob = json.dumps({"code": code_version(), "settings": _settings_record(settings),
                       "label": target.label, "inputs": digests}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _settings_record(s: Settings) -> dict:
    # The model's path may differ between machines; its content is in the inputs' digests.
    d = asdict(s)
    d["model"] = None if s.model is None else os.path.basename(s.model)
    # Unset (or the default), these are not part of the key: results of catalogues without them keep theirs.
    if d["field_share"] is None:
        del d["field_share"]
    if d["placement"]:
        del d["placement"]
    if not d["untangle"]:
        del d["untangle"]
    return d


def result_paths(out, garment, target):
    """``(<out>/<garment>/<target>.obj, .json)``."""
    folder = Path(os.fspath(out)) / garment
    return folder / f"{target}.obj", folder / f"{target}.json"


def write_atomic(path, data: bytes):
    """Write ``data`` to ``path`` whole or not at all: a temporary file beside it, then a rename."""
    path = Path(path)
    tmp = path.with_name(f"{PARTIAL_PREFIX}{uuid.uuid4().hex[:12]}-{path.name}")
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def remove_partial_files(out) -> int:
    """Remove temporary files a stopped writer left under ``out``; how many there were."""
    n = 0
    out = Path(os.fspath(out))
    if not out.is_dir():
        return 0
    for p in out.rglob(f"{PARTIAL_PREFIX}*"):
        try:
            p.unlink()
            n += 1
        except FileNotFoundError:
            pass
    return n


def read_record(json_path):
    """The record beside a result, or None when it is missing or unreadable."""
    try:
        rec = json.loads(Path(json_path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) else None


def _intact(obj_path, record) -> bool:
    try:
        return file_digest(obj_path) == record.get("output_sha256")
    except OSError:
        return False


# ----------------------------------------------------------------------------------------------
# The work on a worker


class _Inputs:
    """Meshes, digests and models read by one worker process, kept across garments.

    Bodies and models are shared by many garments: read and hashed once per process, and read again
    only when the file changes (size or modification time).
    """

    def __init__(self, limit=64):
        self.limit = limit
        self.cache = {}

    def _stat(self, path):
        st = os.stat(path)
        return (os.path.abspath(path), st.st_size, st.st_mtime_ns)

    def digest(self, path):
        return self._get(path, "digest", lambda: file_digest(path))

    def mesh(self, path, name):
        return self._get(path, ("mesh", name), lambda: read_obj(path, name=name))

    def rig(self, files: RigFiles, n_vertices):
        """The source body's Rig (skeleton, joints, weights) from the catalogue's rig files."""
        key = (self._stat(files.skeleton), self._stat(files.weights), n_vertices)
        def make():
            skeleton = read_skeleton(files.skeleton)
            return Rig(skeleton, read_joints(files.source_joints, skeleton, "rig.joints"),
                       read_weights(files.weights, n_vertices))

        return self._get(files.source_joints, ("rig", key), make)

    def joints(self, path, skeleton):
        """A target's joints file, checked against the skeleton (or its bones, for a skeleton named otherwise:
        ``Landmarks``)."""
        return self._get(path, ("joints", self._stat(skeleton.name)),
                         lambda: read_target_skeleton(path, skeleton, "rig.joints"))

    def frames(self, path, skeleton):
        """A target's bone frames, where its joints file is a bones file of the skeleton's own bones with their
        rolls (``naming.read_target_frames``), else None."""
        return self._get(path, ("frames", self._stat(skeleton.name)), lambda: read_target_frames(path, skeleton))

    def registration(self, source_path, source_body, target_path, target_body):
        """The source body fitted onto a target of another mesh (``registration.register``, made once per process
        for every garment of that source and target), with the warnings the fit logged; (None, []) for a target of
        the source's mesh (or that mesh with every face turned)."""
        if as_same_mesh(source_body, target_body) is not None:
            return None, []

        def make():
            with fitting_warnings() as said:
                fit = registration_for(source_body, target_body, cache=False)
            return fit, list(said)

        return self._get(target_path, ("registration", self._stat(source_path)), make)

    def model(self, path, field_share=None, use_placement=True):
        """The model file (``model_files.ModelFile``, any kind)."""

        return self._get(path, ("model", field_share, use_placement),
                         lambda: read_model_file(path, field_share=field_share, use_placement=use_placement))

    def _get(self, path, what, make):
        key = (self._stat(path), what)
        if key not in self.cache:
            if len(self.cache) >= self.limit:
                self.cache.pop(next(iter(self.cache)))
            self.cache[key] = make()
        return self.cache[key]


_INPUTS = _Inputs()


@contextlib.contextmanager
def fitting_warnings():
    """The warnings the registration (``garment_transfer.fitting``) logs in this thread meanwhile, collected in the
    list yielded: a record keeps them (a worker's log is not the user's)."""
    said, ident = [], threading.get_ident()

    class Collect(logging.Handler):
        def emit(self, record):
            if record.thread == ident:
                said.append(record.getMessage())

    handler = Collect(logging.WARNING)
    logger = logging.getLogger("garment_transfer.fitting")
    logger.addHandler(handler)
    try:
        yield said
    finally:
        logger.removeHandler(handler)


def clear_input_cache():
    """Forget the meshes, digests and models this process has read (the next garment reads them again)."""
    _INPUTS.cache.clear()


def _error_text(exc) -> str:
    if isinstance(exc, FileNotFoundError):
        return f"{exc.filename}: file not found"
    if isinstance(exc, OSError):
        return f"{exc.filename}: cannot be read ({exc.strerror or exc})"
    if isinstance(exc, (GarmentTransferError, ValueError)):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def _where() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def run_garment(job: GarmentJob, out, run_id: str = "", stop=None) -> list:
    """Transfer one garment to all its targets; write each result; return one record per target.

    Runs on a worker (or in the calling process). Pairs whose result is present with the same key are
    not done again: ``skipped``, or ``done`` when an earlier attempt of this same run (``run_id``)
    made them, as after a worker was lost. A failing pair is recorded with its error and the others
    go on; a garment or source body that cannot be used fails all its pairs.

    Parameters
    ----------
    job : GarmentJob
    out : str or Path
        The results folder (seen by every worker at the same path).
    run_id : str
        Identifies the run in each written record.
    stop : callable, optional
        Called before each pair; True stops the garment (its remaining pairs are ``not run``).

    Returns
    -------
    list of dict
        Per target, in order: ``garment``, ``target``, ``label``, ``outcome`` (see ``OUTCOMES``),
        ``seconds``, ``prepare_seconds``, the metrics of ``metrics.evaluate``, ``output``, ``key``,
        ``worker`` and ``error``.
    """
    t_start = (time.perf_counter(), time.process_time())
    out = Path(os.fspath(out))
    records = [{"garment": job.name, "target": t.name, "label": t.label, "outcome": "not run"}
               for t in job.targets]
    s = job.settings
    todo = []
    try:
        common = {"garment": _INPUTS.digest(job.file), "source_body": _INPUTS.digest(job.source_file)}
        if s.method == "model":
            common["model"] = _INPUTS.digest(s.model)
    except OSError as exc:
        return _fail_all(records, _error_text(exc), t_start)
    for rec, t in zip(records, job.targets):
        try:
            digests = dict(common, target_body=_INPUTS.digest(t.body))
            if t.reference is not None:
                digests["reference"] = _INPUTS.digest(t.reference)
            if job.rig is not None and t.joints is not None:
                digests.update(skeleton=_INPUTS.digest(job.rig.skeleton), weights=_INPUTS.digest(job.rig.weights),
                               source_joints=_INPUTS.digest(job.rig.source_joints),
                               target_joints=_INPUTS.digest(t.joints))
        except OSError as exc:
            rec.update(outcome="failed", error=_error_text(exc))
            continue
        rec["key"] = pair_key(s, t, digests)
        obj_path, json_path = result_paths(out, job.name, t.name)
        old = read_record(json_path)
        if old is not None and old.get("key") == rec["key"] and _intact(obj_path, old):
            rec.update({k: old.get(k) for k in ("seconds", "prepare_seconds", "worker", "registered", *METRIC_KEYS)
                        if k in old})
            rec.update(outcome="done" if run_id and old.get("run_id") == run_id else "skipped",
                       output=str(obj_path))
            continue
        todo.append((rec, t, digests))
    if not todo:
        return _finish(records, t_start)

    t0 = time.perf_counter()
    try:
        source_body = _INPUTS.mesh(job.source_file, job.source)
        garment = _read_garment(job.file)
        model = _INPUTS.model(s.model, s.field_share, s.placement) if s.method == "model" else None
        prepared = prepare_garment(source_body, garment, interpolate=s.interpolate,
                                   stiffness=s.stiffness, need_solver=s.method != "surface")
    except Exception as exc:  # noqa: BLE001 - any failure of the garment is recorded for its pairs
        for rec, _, _ in todo:
            rec.update(outcome="failed", error=_error_text(exc))
        return _finish(records, t_start)
    prepare_seconds = time.perf_counter() - t0
    (out / job.name).mkdir(parents=True, exist_ok=True)
    for rec, t, digests in todo:
        if stop is not None and stop():
            break
        t1 = time.perf_counter()
        try:
            target_body = _INPUTS.mesh(t.body, t.name)
            options = dict(method=s.method, **(model.transfer_arguments() if model else {}), target=t.label,
                           offset=s.offset, fix_penetration=s.fix_penetration, interpolate=s.interpolate,
                           stiffness=s.stiffness)
            if job.rig is not None and t.joints is not None:
                # Posed into the target's rest pose first where it stands otherwise (the garment prepared on the
                # source at rest serves the others).
                rig = _INPUTS.rig(job.rig, source_body.n_vertices)
                with fitting_warnings() as fit_said:
                    result, registration = transfer_across_rest_poses(
                        source_body, target_body, garment, rig, _INPUTS.joints(t.joints, rig.skeleton),
                        _INPUTS.frames(t.joints, rig.skeleton), cache=False, prepared=prepared,
                        untangle=s.untangle, **options)
            else:
                # A target of another mesh: the source fitted onto it once per worker, for every garment.
                registration, fit_said = _INPUTS.registration(job.source_file, source_body, t.body, target_body)
                result, _ = transfer_to_any_body(source_body, target_body, garment, prepared=prepared,
                                                 registration=registration, cache=False, **options)
            reference = _read_garment(t.reference) if t.reference is not None else None
            obj_path, json_path = result_paths(out, job.name, t.name)
            text = obj_text(garment, result.V, header=f"Garment Transfer: {job.name} on {t.name} ({s.method})",
                            path=obj_path).encode("utf-8", errors="surrogateescape")
            write_atomic(obj_path, text)
            # Measured on the file as written and read back, against the target as given (the record, written
            # last, is what marks the pair done). Without a reference: the design (MDC) and penetration only;
            # the drape error against the body-driven fit would cost as much again and judge nothing the
            # transfer did not aim at.
            written = read_obj(obj_path).V
            metrics = evaluate(garment, garment.with_vertices(written), target_body, reference=reference)
            rest_pose = result.info.get("rest_pose")
            if rest_pose is not None and rest_pose["posed"]:
                # Where the posed target crosses or closes on itself no cloth can be outside both surfaces.
                rest_pose["written"] = posed_counts(written, garment, target_body, result.info["offset"],
                                                    rest_V=target_at_rest(source_body, target_body, registration),
                                                    name=str(obj_path), own=False)
        except Exception as exc:  # noqa: BLE001 - recorded; the other targets go on
            rec.update(outcome="failed", error=_error_text(exc), seconds=time.perf_counter() - t1)
            continue
        rec.update({k: _plain(metrics.get(k)) for k in METRIC_KEYS})
        rec.update(outcome="done", output=str(obj_path), worker=_where(), registered=registration is not None,
                   seconds=time.perf_counter() - t1, prepare_seconds=prepare_seconds)
        used = {} if model is None else {k: v for k, v in model.summary().items()
                                         if k in ("model_kind", "field_share", "placement", "nearest_garments")}
        record = dict(rec, run_id=run_id, code=code_version(), settings=_settings_record(s), **used,
                      inputs=digests, stage_seconds=result.seconds,
                      crossings_left=int(metrics["garment_edges_through_body"] + metrics["body_edges_through_garment"]),
                      check={k: metrics[k] for k in CHECK_KEYS},
                      warnings=list(fit_said) + result_warnings(metrics, str(obj_path))
                      + (rest_pose or {}).get("warnings", [])
                      + (rest_pose or {}).get("written", {}).get("warnings", [])
                      + fold_warnings(rest_pose or {}, metrics["self_intersections_new"], str(obj_path),
                                      "the setting untangle (batch --untangle)"),
                      output_sha256=hashlib.sha256(text).hexdigest())
        if rest_pose is not None:
            record["rest_pose"] = rest_pose
        if registration is not None:
            record["registration"] = registration.summary()
        write_atomic(json_path, (json.dumps(record, indent=1) + "\n").encode("utf-8"))
    return _finish(records, t_start)


def _read_garment(path):
    return read_obj(path)


def _plain(x):
    if x is None or isinstance(x, (str, bool, int)):
        return x
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return v if math.isfinite(v) else None


def _fail_all(records, error, t_start):
    for rec in records:
        rec.update(outcome="failed", error=error)
    return _finish(records, t_start)


def _finish(records, t_start):
    # Wall and CPU time of the whole garment on its worker (the CPU time counts every thread of the
    # worker process: what the garment costs in core-seconds on a machine that is not shared).
    elapsed, cpu = time.perf_counter() - t_start[0], time.process_time() - t_start[1]
    for rec in records:
        rec["garment_seconds"] = elapsed
        rec["garment_cpu_seconds"] = cpu
    return records


# ----------------------------------------------------------------------------------------------
# Executors: one interface for this process, a process pool and Dask


_STOP_EVENT = None


def _pool_init(event):
    # Only the driver handles Ctrl+C: it asks the workers to stop between pairs through this event,
    # so that no worker is cut in the middle of a write.
    import signal

    global _STOP_EVENT
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _STOP_EVENT = event


def _pool_stop():
    return _STOP_EVENT is not None and _STOP_EVENT.is_set()


def _pool_run(job, out, run_id):
    return run_garment(job, out, run_id, stop=_pool_stop)


class _Serial:
    """Garments one after the other in this process."""

    kind = "serial"
    workers = 1

    def __init__(self):
        self.stopped = False
        self.pending = []

    def submit(self, jobs, out, run_id):
        self.pending = list(jobs)
        self.args = (os.fspath(out), run_id)

    def results(self):
        while self.pending and not self.stopped:
            job = self.pending[0]
            records = run_garment(job, *self.args, stop=lambda: self.stopped)
            self.pending.pop(0)
            yield job, records, None

    def stop(self):
        self.stopped = True

    def close(self):
        pass


class _Pool:
    """A local process pool (no Dask needed)."""

    kind = "processes"

    def __init__(self, workers):
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        # spawn: a forked child would inherit the driver's threads' locks (tqdm, logging).
        ctx = mp.get_context("spawn")
        self.event = ctx.Event()
        self.workers = workers
        self.pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_pool_init,
                                        initargs=(self.event,))
        self.pending = {}

    def submit(self, jobs, out, run_id):
        self.pending = {self.pool.submit(_pool_run, job, os.fspath(out), run_id): job for job in jobs}

    def results(self):
        from concurrent.futures import as_completed

        for f in as_completed(list(self.pending)):
            job = self.pending.pop(f)
            try:
                yield job, f.result(), None
            except BaseException as exc:  # noqa: BLE001 - a lost worker process fails the garment's pairs
                if isinstance(exc, KeyboardInterrupt):
                    raise
                yield job, None, exc

    def stop(self):
        self.event.set()
        for f in self.pending:
            f.cancel()

    def close(self):
        self.pool.shutdown(wait=True, cancel_futures=True)


def _dask_stop(name):
    from distributed import Event

    return Event(name).is_set()


def _dask_run(job, out, run_id, stop_name):
    return run_garment(job, out, run_id, stop=lambda: _dask_stop(stop_name))


class _Dask:
    """A Dask cluster: a local one, or the one behind a scheduler's address."""

    kind = "dask"

    def __init__(self, workers=None, scheduler=None, client=None):
        try:
            import distributed
        except ImportError:
            raise MissingDependency(
                "Dask runs need the dask and distributed packages: pip install "
                "'dask[distributed]' (see requirements.txt for the tested version)") from None
        self.cluster = None
        if client is not None:
            self.client, self.own_client = client, False
        elif scheduler:
            try:
                self.client = distributed.Client(scheduler, timeout="30s")
            except (OSError, TimeoutError) as exc:
                raise GarmentTransferError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") \
                    from None
            self.own_client = True
        else:
            # One thread per worker process: garments run side by side in processes (the GIL), and
            # each keeps its own cache of bodies.
            import dask

            # No dashboard, so nobody reads the workers' statistical profile: its sampling thread
            # takes the GIL every 10 ms from the transfer, which costs most on a busy machine.
            with dask.config.set({"distributed.worker.profile.enabled": False}):
                self.cluster = distributed.LocalCluster(n_workers=workers, threads_per_worker=1,
                                                        processes=True, dashboard_address=None)
            self.client, self.own_client = distributed.Client(self.cluster), True
        self.workers = sum(w.get("nthreads", 1) for w in
                           self.client.scheduler_info(n_workers=-1)["workers"].values())
        self.stop_name = None
        self.pending = {}

    def submit(self, jobs, out, run_id):
        self.stop_name = f"garment-transfer-stop-{run_id}"
        futures = self.client.map(_dask_run, list(jobs), out=os.fspath(out), run_id=run_id,
                                  stop_name=self.stop_name, pure=False,
                                  key=[f"garment-{job.name}-{run_id}" for job in jobs])
        self.pending = {f.key: (f, job) for f, job in zip(futures, jobs)}

    def results(self):
        import distributed

        for f in distributed.as_completed([f for f, _ in self.pending.values()]):
            _, job = self.pending.pop(f.key)
            try:
                yield job, f.result(), None
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: the worker died too often
                yield job, None, exc
            finally:
                f.release()

    def stop(self):
        import distributed

        if self.stop_name:
            distributed.Event(self.stop_name, client=self.client).set()
        # Queued garments are dropped; running ones stop after their current pair and report.
        running = {k for keys in self.client.processing().values() for k in keys}
        self.client.cancel([f for f, _ in self.pending.values() if f.key not in running])

    def close(self):
        if self.own_client:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def make_executor(workers=None, scheduler=None, dask=False, client=None):
    """The executor for a run: this process, a process pool, a local Dask cluster, or a Dask scheduler.

    Parameters
    ----------
    workers : int, optional
        Local workers (default: every core). 1 runs in this process (without Dask).
    scheduler : str, optional
        A Dask scheduler's address (``tcp://host:8786``): use its cluster.
    dask : bool
        A local Dask cluster of ``workers`` processes instead of a process pool.
    client : distributed.Client, optional
        An existing Dask client.
    """
    if client is not None or scheduler:
        return _Dask(scheduler=scheduler, client=client)
    workers = workers or os.cpu_count() or 1
    if dask:
        return _Dask(workers=workers)
    return _Serial() if workers == 1 else _Pool(workers)


# ----------------------------------------------------------------------------------------------
# The driver


@dataclass
class BatchSummary:
    """What a run did.

    Attributes
    ----------
    records : list of dict
        One per pair, in catalogue order (see ``run_garment``).
    counts : dict
        Pairs per outcome.
    seconds : float
        Wall time of the run.
    interrupted : bool
    info : dict
        Run id, executor, workers, catalogue, code version.
    """

    records: list
    counts: dict
    seconds: float
    interrupted: bool = False
    info: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Every pair transferred (now or in an earlier run)."""
        return not self.interrupted and all(r["outcome"] in ("done", "skipped") for r in self.records)


def run_batch(catalogue: Catalogue, out, *, workers=None, scheduler=None, dask=False, client=None,
              executor=None, progress=None) -> BatchSummary:
    """Transfer every garment of a catalogue to each of its targets; write results and a summary.

    Parameters
    ----------
    catalogue : Catalogue
    out : str or Path
        Results folder (made if missing). With a Dask scheduler, every worker must see it, and the
        catalogue's files, at the same paths.
    workers, scheduler, dask, client
        See ``make_executor``.
    executor : optional
        An executor made by ``make_executor`` (then the others are ignored); the caller closes it.
    progress : callable, optional
        ``progress(done, total, record)`` after each pair's record comes back (``record`` None at
        the start); returning True stops the run as Ctrl+C does.

    Returns
    -------
    BatchSummary
        Also written to ``<out>/summary.json`` and ``<out>/summary.csv``.

    Raises
    ------
    files.OutputError
        Before any work, when ``out`` or a file the run would write harms an input
        (``check_batch_outputs``), or cannot be written.

    Notes
    -----
    Ctrl+C (KeyboardInterrupt) or a progress callback returning True stops the run: queued
    garments are dropped, running ones stop after their current pair, temporary files are removed,
    and the summary lists what was done (``interrupted`` True; pairs not reached are ``not run``).
    """
    check_batch_outputs(catalogue, out)
    out = Path(os.fspath(out)).absolute()
    out.mkdir(parents=True, exist_ok=True)
    removed = remove_partial_files(out)
    if removed:
        log.info("removed %d temporary files left by an earlier, stopped run", removed)
    run_id = f"{time.strftime('%Y%m%dT%H%M%S')}-{uuid.uuid4().hex[:8]}"
    start = time.perf_counter()
    total = catalogue.n_pairs
    own = executor is None
    ex = executor if executor is not None else make_executor(workers, scheduler, dask, client)
    log.info("run %s: %d garments, %d pairs from %s on %s (%d workers) into %s", run_id,
             len(catalogue.jobs), total, catalogue.origin, ex.kind, ex.workers, out)
    results = {}
    interrupted = False
    done = 0
    if progress is not None:
        progress(0, total, None)

    def collect(job, records, exc):
        nonlocal done
        if exc is not None:
            if interrupted and _is_cancel(exc):
                return
            records = [{"garment": job.name, "target": t.name, "label": t.label,
                        "outcome": "failed", "error": f"the worker was lost: {_error_text(exc)}"}
                       for t in job.targets]
        results[job.name] = records
        for rec in records:
            _log_record(rec)
            done += 1
            if progress is not None and progress(done, total, rec) and not interrupted:
                raise KeyboardInterrupt

    try:
        try:
            ex.submit(catalogue.jobs, out, run_id)
            for item in ex.results():
                collect(*item)
        except KeyboardInterrupt:
            interrupted = True
            log.warning("interrupted: the workers stop after their current pair (Ctrl+C again: at once)")
            try:
                ex.stop()
                # The garments under way finish their current pair and report what they did.
                for item in ex.results():
                    collect(*item)
            except KeyboardInterrupt:
                pass
    finally:
        if own:
            try:
                ex.close()
            except KeyboardInterrupt:
                interrupted = True
        removed = remove_partial_files(out)
        if removed:
            log.info("removed %d temporary files of interrupted writes", removed)
    records = []
    for job in catalogue.jobs:
        records += results.get(job.name) or [
            {"garment": job.name, "target": t.name, "label": t.label, "outcome": "not run"}
            for t in job.targets]
    for rec in records:
        if rec["outcome"] == "not run":
            _recover(rec, out, run_id)
    counts = {o: sum(r["outcome"] == o for r in records) for o in OUTCOMES}

    info = {"run_id": run_id, "catalogue": catalogue.origin, "out": str(out), "executor": ex.kind,
            "workers": ex.workers, "scheduler": scheduler, "version": __version__,
            "code": code_version()}
    summary = BatchSummary(records, counts, time.perf_counter() - start, interrupted, info)
    write_summary(summary, out)
    log.info("run %s: %s in %.1f s%s", run_id, ", ".join(f"{v} {k}" for k, v in counts.items() if v),
             summary.seconds, " (interrupted)" if interrupted else "")
    return summary


def _is_cancel(exc):
    return type(exc).__name__ in ("CancelledError", "FutureCancelledError")


def _recover(rec, out, run_id):
    """A pair whose garment's report never came back (stopped run) but whose result this run wrote."""
    obj_path, json_path = result_paths(out, rec["garment"], rec["target"])
    old = read_record(json_path)
    if old is not None and old.get("run_id") == run_id and _intact(obj_path, old):
        rec.update({k: old.get(k) for k in ("seconds", "prepare_seconds", "worker", "key", "registered",
                                            *METRIC_KEYS) if k in old})
        rec.update(outcome="done", output=str(obj_path))


def _log_record(rec):
    if rec["outcome"] == "failed":
        log.warning("FAILED %s -> %s: %s", rec["garment"], rec["target"], rec.get("error"))
    elif rec["outcome"] == "not run":
        log.info("not run %s -> %s (stopped)", rec["garment"], rec["target"])
    else:
        mdc = rec.get("mdc")
        log.info("%s %s -> %s: MDC %s, %s inside, %.2f s", rec["outcome"], rec["garment"], rec["target"],
                 "-" if mdc is None else f"{mdc:.4f}", _pct(rec.get("penetration_ratio")),
                 rec.get("seconds") or 0.0)


def _pct(x):
    return "-" if x is None else f"{100 * x:.2f}%"


def write_summary(summary: BatchSummary, out):
    """``<out>/summary.json`` (everything) and ``<out>/summary.csv`` (one row per pair), atomically."""
    out = Path(os.fspath(out))
    doc = {"info": summary.info, "interrupted": summary.interrupted, "seconds": summary.seconds,
           "counts": summary.counts, "pairs": summary.records}
    write_atomic(out / "summary.json", (json.dumps(doc, indent=1) + "\n").encode("utf-8"))
    buf = io.StringIO()
    w = csv.DictWriter(buf, CSV_COLUMNS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for rec in summary.records:
        w.writerow({k: ("" if rec.get(k) is None else rec.get(k)) for k in CSV_COLUMNS})
    write_atomic(out / "summary.csv", buf.getvalue().encode("utf-8"))
