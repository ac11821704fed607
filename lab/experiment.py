"""The one experiment loop: train the models a set of methods needs, transfer held-out garments with every
method to every target body, and evaluate each result against the reference garment on that body.

The demo, the benchmark report and the held-out studies are each one call of ``run_experiment`` with
their own data: which methods (keys of ``METHODS``), which garments are trained on and tested (folds),
which bodies. Figures are ``garment_transfer.metrics.evaluate``'s.
"""

from __future__ import annotations

import logging
import re
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from garment_transfer.geometry.gradients import deformation_gradients
from garment_transfer.learning.dataset import build_training_fields, load_dataset
from garment_transfer.learning.garment_training import (
    FIELD_EPOCHS,
    PLACEMENT_RESIDUAL,
    nearest_garments,
    placement_tables,
    train_garment_model,
    train_placement_ensemble,
    training_tables,
)
from garment_transfer.learning.garment_training import PLACEMENT_EPOCHS as PRODUCT_PLACEMENT_EPOCHS
from garment_transfer.learning.garment_training import PLACEMENT_MEMBERS as PRODUCT_PLACEMENT_MEMBERS
from garment_transfer.learning.model_files import ModelFile, read_model_file, save_garment_fit_bundle
from garment_transfer.learning.placement import LIBRARY_SHARE, MixedPlacement, true_offsets
from garment_transfer.learning.training import default_threads, train_model
from garment_transfer.pipeline.metrics import evaluate
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment

from .length_placement import LengthMixed, LengthPlacement

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Method:
    """One way of transferring a garment, as the experiments compare them.

    Attributes
    ----------
    key, label : str
    kind : {"model", "direct", "surface", "external"}
        A ``transfer_garment`` method, or ``external``: results computed elsewhere (Blender's Surface
        Deform) and handed to ``run_experiment``.
    variant : str, optional
        For ``model``: the training variant (a key of ``VARIANTS``); ``product``: the model file that ``train``
        writes by default, read back as ``transfer --model`` reads it (its own field share and placement).
    field : str
        For ``model``: how the model's field for a new garment is read (``SharedDeformationModel.body_field``'s
        ``how``), ``"oracle"``: the held-out garment's own embedded deformation, or ``"half"``: a garment
        model's field halfway back to the body's own.
    interpolate, fix_penetration : bool
        ``transfer_garment``'s options.
    energy : str
        ``prepare_garment``'s: the Poisson solve's finite-element energy (``"gradients"``) or the paper's
        sum over edges (``"edges"``).
    anchoring : str
        ``transfer_garment``'s: ``everywhere`` or ``contact``.
    placement : str, optional
        ``transfer_garment``'s ``placement``: ``"file"`` (the ``product`` model file's own), ``"model"`` (the
        learned placement, trained with the
        fold's garments), ``"nearest"`` (the fold's nearest garments' placement, ``placement.NearestGarments``),
        ``"mixed"`` (the two mixed, ``placement.MixedPlacement`` at ``placement.LIBRARY_SHARE``, as ``train
        --kind garment`` writes it), ``"shrunk"`` (the mix shrunk where its two
        predictions disagree by ``DISAGREEMENT_SHRINK`` below, ``placement.shrink_gain``) or
        ``"oracle"`` (the held-out garment's own placement, from its simulation).
    field_share : float
        For ``field="half"``: the share of the garment model's field (``with_field_share``).
    """

    key: str
    label: str
    kind: str
    variant: str | None = None
    field: str = "mean_latent"
    interpolate: bool = True
    fix_penetration: bool = True
    energy: str = "gradients"
    anchoring: str = "everywhere"
    placement: str | None = None
    field_share: float = 0.5


#: Training variants: ``train_model`` keyword arguments, or (``garment_model``) those of
#: ``train_garment_model``.
#: ``product``: the garment fit model and its learned placement as ``train`` writes them by default
#: (``train_product``).
VARIANTS = {"shared": {"masked": True}, "paper": {"masked": False}, "hidden": {"hidden": [32]},
            "garment": {"garment_model": True}, "garment_nolabel": {"garment_model": True, "use_label": False},
            "garment_blind": {"garment_model": True, "garment_inputs": False},
            "placement": {"placement_model": True}, "product": {"product": True}}
#: Passes over the samples of the garment model, whatever ``epochs`` the shared model gets.
GARMENT_EPOCHS = 6
#: Passes over the samples of the placement model.
PLACEMENT_EPOCHS = 30
#: Placement models trained (seeds ``seed`` .. ``seed + n - 1``) and averaged (``placement.PlacementEnsemble``);
#: 1 (the lab's default, as its recorded figures): the single model.
PLACEMENT_MEMBERS = 1
#: Further ``garment_training.train_placement_model`` arguments of every placement the lab trains (hidden
#: widths, learning rate and its schedule, weight decay, a loss weighted by bound points); empty: its defaults.
PLACEMENT_OPTIONS = {}
#: The nearest garments' similarity width (None: ``placement.SIMILARITY_WIDTH``).
NEAREST_WIDTH = None
#: Garment fit models trained (seeds ``seed`` .. ``seed + n - 1``) and averaged (``FieldEnsemble``); 1: the
#: single model.
FIELD_MEMBERS = 1
#: The ``"shrunk"`` placement's factor ``c`` of ``placement.shrink_gain`` (1: the variance as estimated).
DISAGREEMENT_SHRINK = 1.0


class FieldEnsemble:
    """Several garment fit models trained alike (other seeds), read as one: the field is the mean of theirs
    (each ``body_field`` at the same field share); anything else is the first member's."""

    conditions_on_garment = True

    def __init__(self, members):
        self.members = list(members)

    def __getattr__(self, name):
        return getattr(self.members[0], name)

    def with_field_share(self, share):
        return FieldEnsemble([m.with_field_share(share) for m in self.members])

    def body_field(self, target, garment=None, source_body=None, target_body=None):
        return sum(m.body_field(target, garment, source_body, target_body) for m in self.members) / len(self.members)


def train_field(tables, targets, seed=0, threads=None, **options):
    """``garment_training.train_garment_model`` of ``GARMENT_EPOCHS`` passes, ``FIELD_MEMBERS`` times (seeds
    ``seed``, ``seed + 1``, ...): the model, or a ``FieldEnsemble`` of them, and the first's info with the
    seconds of all."""
    trained = [train_garment_model(tables, targets, epochs=GARMENT_EPOCHS, seed=seed + j, threads=threads, **options)
               for j in range(FIELD_MEMBERS)]
    info = dict(trained[0][1], seconds=sum(i["seconds"] for _, i in trained))
    if len(trained) == 1:
        return trained[0][0], info
    return FieldEnsemble([m for m, _ in trained]), info


def train_placement(tables, targets, seed=0, threads=None, **options):
    """``garment_training.train_placement_ensemble`` of ``PLACEMENT_MEMBERS`` members, ``PLACEMENT_EPOCHS``
    passes each, with ``PLACEMENT_OPTIONS`` (``options`` take precedence)."""
    return train_placement_ensemble(tables, targets, PLACEMENT_MEMBERS, seed=seed, epochs=PLACEMENT_EPOCHS,
                                    threads=threads, **{**PLACEMENT_OPTIONS, **options})


def train_product(dataset, source, targets, garments, tables, path, seed=0, threads=None, epochs=FIELD_EPOCHS,
                  placement_epochs=PRODUCT_PLACEMENT_EPOCHS, placement_members=PRODUCT_PLACEMENT_MEMBERS):
    """The model file that ``train`` writes by default, from tables already built, read back as ``transfer
    --model`` reads it.

    The steps and settings of ``garment_training.train_garment_fit_from_dataset`` (its defaults unless
    given): the garment fit model, the placement networks learning the departure from the training garments'
    mean placement, the nearest garments' placement mixed in at ``placement.LIBRARY_SHARE``, one bundle.

    Parameters
    ----------
    dataset : Dataset
    source : str
    targets, garments : list of str
        In the order of ``tables``.
    tables : dict
        ``garment_training.training_tables`` of these garments and targets (``placement_tables`` are added
        when missing).
    path : str or Path
        The model file to write.
    seed, threads, epochs, placement_epochs, placement_members
        ``train --kind garment``'s ``--seed``, ``--threads``, ``--epochs``, ``--placement-epochs`` and
        ``--placement-members``.

    Returns
    -------
    model_file : ModelFile
        ``read_model_file(path)``.
    info : dict
        ``seconds`` (training and writing), ``epochs``, ``samples``, ``losses`` (the field model's),
        ``placement`` (the placement's ``seconds``, ``samples``, ``epochs``, ``members``, ``final_loss``).
    """
    t0 = time.perf_counter()
    # As train does: the same data, seed and threads give the same model (torch's own default is every core).
    threads = default_threads() if threads is None else max(1, int(threads))
    field, field_info = train_garment_model(tables, targets, epochs=int(epochs), seed=seed, threads=threads)
    if "offset" not in tables:
        placement_tables(dataset, source, targets, list(garments), tables)
    placement, placement_info = train_placement_ensemble(tables, targets, int(placement_members), seed=seed,
                                                         epochs=int(placement_epochs), threads=threads,
                                                         residual=PLACEMENT_RESIDUAL)
    library = nearest_garments(tables, targets, list(garments))
    dataset_info = {"folder": dataset.folder.name, "units": dataset.units, "up_axis": dataset.up_axis}
    for m in [field, *getattr(placement, "members", [placement])]:
        m.metadata["dataset"] = dataset_info
    save_garment_fit_bundle(path, field, placement, dataset=dataset_info, library=library,
                            library_share=LIBRARY_SHARE)
    info = dict(field_info, seconds=time.perf_counter() - t0,
                placement={k: placement_info[k] for k in ("seconds", "samples", "epochs", "members")}
                | {"final_loss": placement_info["losses"][-1]})
    return read_model_file(path), info


#: Every method the lab compares, by key.
METHODS = {m.key: m for m in (
    Method("ours", "Ours: the garment fit model and its learned placement, as `train` writes them by default and "
           "`transfer --model` uses them (half the field, the placement mixed with the nearest garments'), "
           "interpolated field, penetration fix", "model", "product", placement="file"),
    Method("shared", "The shared deformation model (masked loss), interpolated field, penetration fix", "model",
           "shared"),
    Method("paper", "Paper as written: model (unmasked loss), nearest-triangle embedding, the paper's Poisson "
           "energy, no fix", "model", "paper", interpolate=False, fix_penetration=False, energy="edges"),
    Method("direct", "Direct deformation transfer: the body's own gradients, interpolated, penetration fix",
           "direct"),
    Method("surface", "Body-driven fit (like Surface Deform): the garment follows the body alone", "surface"),
    Method("surface_deform", "Blender's Surface Deform modifier bound to the source body (no fix)", "external"),
    Method("mean_field", "Model's mean of the training fields (no network)", "model", "shared",
           field="mean_field"),
    Method("hidden_mean_latent", "Model with a 32-unit sigmoid hidden layer, decoder at the mean latent",
           "model", "hidden"),
    Method("hidden_mean_decoded", "Model with a 32-unit sigmoid hidden layer, mean of the decoded fields",
           "model", "hidden", field="mean_decoded"),
    Method("oracle", "The held-out garment's own embedded deformation (the best a body field can do here)",
           "model", "shared", field="oracle"),
    Method("direct_contact", "Direct deformation transfer, anchored only where the garment rests on the body",
           "direct", anchoring="contact"),
    Method("oracle_contact", "The held-out garment's own embedded deformation, contact anchors", "model",
           "shared", field="oracle", anchoring="contact"),
    Method("garment", "Garment fit model (garment + target features, label), anchors everywhere", "model",
           "garment"),
    Method("garment_contact", "Garment fit model, anchored only where the garment rests on the body", "model",
           "garment", anchoring="contact"),
    Method("garment_nolabel_contact", "Garment fit model without the target label (body features only), "
           "contact anchors", "model", "garment_nolabel", anchoring="contact"),
    Method("garment_blind_contact", "Garment fit model without the garment's distance and direction, contact "
           "anchors", "model", "garment_blind", anchoring="contact"),
    Method("garment_placed", "Garment fit model and learned placement, anchors everywhere", "model", "garment",
           placement="model"),
    Method("garment_placed_contact", "Garment fit model and learned placement, contact anchors", "model",
           "garment", anchoring="contact", placement="model"),
    Method("direct_placed", "Direct deformation transfer and learned placement, anchors everywhere", "direct",
           placement="model"),
    Method("garment_half_placed", "Garment fit model's field halfway back to the body's own, learned placement, "
           "anchors everywhere", "model", "garment", field="half", placement="model"),
    Method("direct_nearest_placed", "Direct deformation transfer and the nearest garments' placement, anchors "
           "everywhere", "direct", placement="nearest"),
    Method("direct_mixed_placed", "Direct deformation transfer and the learned placement mixed with the nearest "
           "garments', anchors everywhere", "direct", placement="mixed"),
    Method("garment_half_nearest_placed", "Garment fit model's field halfway back to the body's own, the nearest "
           "garments' placement, anchors everywhere", "model", "garment", field="half", placement="nearest"),
    Method("direct_shrunk_placed", "Direct deformation transfer and the mixed placement, shrunk where its two "
           "predictions disagree, anchors everywhere", "direct", placement="shrunk"),
    Method("garment_half_shrunk_placed", "Garment fit model's field halfway back to the body's own, the mixed "
           "placement shrunk where its two predictions disagree, anchors everywhere", "model", "garment",
           field="half", placement="shrunk"),
    Method("direct_length_placed", "Direct deformation transfer and the placement from the cloth's length (nothing "
           "learned), anchors everywhere", "direct", placement="length"),
    Method("garment_half_length_placed", "Garment fit model's field halfway back to the body's own, the networks', "
           "the nearest garments' and the length-keeping placements, a third each, anchors everywhere", "model",
           "garment", field="half", placement="length_mixed"),
    Method("garment_half_mixed_placed", "Garment fit model's field halfway back to the body's own, the learned "
           "placement mixed with the nearest garments', anchors everywhere", "model", "garment", field="half",
           placement="mixed"),
    Method("direct_oracle_placed", "Direct deformation transfer and the held-out garment's own placement, "
           "anchors everywhere", "direct", placement="oracle"),
    Method("garment_oracle_placed", "Garment fit model and the held-out garment's own placement, anchors "
           "everywhere", "model", "garment", placement="oracle"),
    Method("garment_oracle_placed_contact", "Garment fit model and the held-out garment's own placement, "
           "contact anchors", "model", "garment", anchoring="contact", placement="oracle"),
    Method("oracle_placed", "The held-out garment's own field and placement, anchors everywhere", "model",
           "shared", field="oracle", placement="oracle"),
    Method("oracle_placed_contact", "The held-out garment's own field and placement, contact anchors", "model",
           "shared", field="oracle", anchoring="contact", placement="oracle"),
)}


class _FixedField:
    """Stands in for a model in ``transfer_garment``: a given body field per target."""

    def __init__(self, model, field_of):
        self._model = model
        self._field_of = field_of
        self.name = model.name
        self.targets = model.targets

    def check_source_body(self, mesh):
        self._model.check_source_body(mesh)

    def same_body(self, mesh):
        # The given fields are on the model's own body: another body is refused, not carried across.
        self._model.check_source_body(mesh)
        return True

    def body_field(self, target):
        return self._field_of(target)


def curve_recorder(curve):
    """A ``train_model`` progress callback appending ``[epoch, seconds, loss]`` to ``curve``."""
    t0 = time.perf_counter()

    def progress(fraction, loss):
        if loss is not None:
            curve.append([len(curve) + 1, time.perf_counter() - t0, float(loss)])
        return False

    return progress


def thin(curve, n=200):
    """At most ``n`` evenly spaced points of a curve, the last one kept."""
    if len(curve) <= n:
        return curve
    idx = np.unique(np.linspace(0, len(curve) - 1, n).round().astype(int))
    return [curve[i] for i in idx]


def field_rms(Q, true_dev, covered):
    """RMS over the covered triangles of the difference between a field Q (M,3,3) and I + true_dev (M,9)."""
    d = Q.reshape(-1, 9)[covered] - (np.eye(3).reshape(9) + true_dev[covered])
    return float(np.sqrt(np.mean(d ** 2)))


def _up_index(up_axis):
    """0, 1 or 2 for a dataset's up axis ("X", "Y", "Z"; Z when not given)."""
    return "XYZ".index((up_axis or "Z").upper()[-1])


def method_of(key):
    """A key of ``METHODS``, or ``garment_share<s>_placed`` / ``garment_share<s>_mixed_placed``: the garment
    model's field at share ``s`` (in [0, 1]) with the learned placement / the mixed placement, anchors
    everywhere (``garment_half_placed`` / ``garment_half_mixed_placed`` at another share)."""
    if key in METHODS:
        return METHODS[key]
    m = re.fullmatch(r"garment_share([0-9.]+)(_mixed)?_placed", key)
    if m is None:
        raise KeyError(f"unknown method {key!r}")
    share = float(m.group(1))
    mixed = bool(m.group(2))
    what = "the learned placement mixed with the nearest garments'" if mixed else "learned placement"
    return Method(key, f"Garment fit model's field at share {share} of the way from the body's own, {what}, "
                  "anchors everywhere", "model", "garment", field="half", placement="mixed" if mixed else "model",
                  field_share=share)


def _field_source(method, model, fields, gi, targets):
    """What ``transfer_garment`` reads a model-based method's body field from."""
    if isinstance(model, ModelFile):
        return model.model
    if method.field == "half":
        return model.with_field_share(method.field_share)
    if method.field == "mean_latent" or getattr(model, "conditions_on_garment", False):
        return model
    if method.field != "oracle":
        return _FixedField(model, lambda t: model.body_field(t, how=method.field))

    def own(t):
        k = targets.index(t)
        dev = np.where(fields.covered[gi][:, None], fields.deviation[gi, k], fields.body_deviation[k])
        return dev.astype(np.float64).reshape(-1, 3, 3) + np.eye(3)

    return _FixedField(model, own)


def _train_product(ds, source, targets, train, tables, model_file, fold, seed, threads, options):
    """``train_product`` into ``model_file(fold)``, or through a temporary file read back and removed."""
    if model_file is not None:
        return train_product(ds, source, targets, train, tables, model_file(fold), seed, threads, **options)
    with tempfile.TemporaryDirectory(prefix="gt_product_") as work:
        return train_product(ds, source, targets, train, tables, Path(work) / "product.npz", seed, threads,
                             **options)


def run_experiment(dataset, source, targets, folds, methods, epochs, reference="simulation", seed=0,
                   threads=None, reference_seconds=None, external=None, field_error=False,
                   on_result=None, on_models=None, progress=None, shared_garments=None, model_file=None,
                   product_options=None):
    """Train, transfer and evaluate: every method on every held-out garment and target.

    Parameters
    ----------
    dataset : str or Path or Dataset
        A dataset folder (``garment_transfer.dataset.load_dataset``), or the dataset itself.
    source : str
        The source body.
    targets : list of str
    folds : list of (list of str, list of str)
        (training garments, test garments); the models are trained once per fold.
    methods : list of str
        Keys of ``METHODS``, in report order.
    epochs : int
    reference : str
        The method name of the reference rows (``simulation`` or ``fitted``).
    seed, threads : int
        ``train_model``'s.
    reference_seconds : dict, optional
        Garment name to the seconds the reference took per body (simulation time).
    external : dict, optional
        Method key to {(garment, target): (V (n,3), seconds cold, seconds reused)} for ``external`` methods.
    field_error : bool
        Also record ``field_rms``: the RMS difference between each method's body field and the test
        garment's own embedded deformation (its target garments must be in the dataset).
    on_result : callable(garment, target, key, garment_mesh, V), optional
        Called with every result (the reference too, under the name ``reference``).
    on_models : callable(fold, {variant: model}), optional
        Called with each fold's trained models.
    progress : callable(fraction, stage), optional
    shared_garments : list of str, optional
        The shared deformation model's variants (those ``train_model`` trains: its training time grows with
        its garments) train on those of a fold's training garments that are in this list (default: on all of
        them, as every other variant).
    model_file : callable(fold) -> path, optional
        Where the ``product`` variant's model file of each fold is written (default: a temporary folder,
        removed when the run ends).
    product_options : dict, optional
        ``train_product``'s training settings (default: ``train --kind garment``'s).

    Returns
    -------
    dict
        ``rows`` (one per fold, garment, target and method: ``evaluate``'s figures plus ``fold``,
        ``garment``, ``target``, ``method``, ``seconds`` (cold: the garment's preparation and the
        transfer), ``seconds_reused`` and ``stages``), ``trainings`` (per fold and variant: seconds,
        epochs, losses, loss ``curve``), ``read_seconds``, ``units``, ``up_axis``.
    """
    methods = [method_of(k) for k in methods]
    external = external or {}
    reference_seconds = reference_seconds or {}
    learned = ("model", "mixed", "shrunk", "length_mixed")
    variants = sorted({m.variant for m in methods if m.kind == "model"}
                      | ({"placement"} if any(m.placement in learned for m in methods) else set()),
                      key=list(VARIANTS).index)

    def step(fraction, stage):
        log.info("%s", stage)
        if progress:
            progress(fraction, stage)

    ds = dataset if hasattr(dataset, "garment") else load_dataset(dataset)
    tests = [g for g in ds.garments if any(g in te for _, te in folds)]
    needed = [g for g in ds.garments if any(g in tr for tr, _ in folds)
              or (g in tests and (field_error or any(m.field == "oracle" for m in methods)))]
    t = time.perf_counter()
    fields = build_training_fields(ds, source, targets, needed, keep_raw=True) if needed else None
    read_seconds = time.perf_counter() - t
    source_body = ds.body(source)
    bodies = {b: ds.body(b) for b in targets}
    body_fields = {b: deformation_gradients(source_body.V, bodies[b].V, source_body.F)[0]
                   for b in targets} if field_error else {}
    dataset_info = {"folder": ds.folder.name, "units": ds.units, "up_axis": ds.up_axis}

    rows, trainings = [], []
    for i, (train, test) in enumerate(folds):
        part = fields.select(train) if variants else None
        models, tables = {}, None
        for v in variants:
            curve = []
            if VARIANTS[v].get("product"):
                tables = tables or training_tables(ds, source, targets, list(train), fields=part)
                model, info = _train_product(ds, source, targets, list(train), tables, model_file, i, seed,
                                             threads, product_options or {})
                models[v] = model
                trainings.append({"fold": i, "test": list(test), "variant": v, "seconds": info["seconds"],
                                  "epochs": info["epochs"], "samples": info["samples"],
                                  "final_loss": info["losses"][-1], "placement": info["placement"],
                                  "garments": len(train), "curve": [[e + 1, None, x] for e, x in
                                                                    enumerate(info["losses"])]})
                continue
            if VARIANTS[v].get("placement_model") or VARIANTS[v].get("garment_model"):
                tables = tables or training_tables(ds, source, targets, list(train), fields=part)
                if VARIANTS[v].get("placement_model"):
                    placement_tables(ds, source, targets, list(train), tables)
                    model, info = train_placement(tables, targets, seed=seed, threads=threads)
                else:
                    options = {k: x for k, x in VARIANTS[v].items() if k != "garment_model"}
                    model, info = train_field(tables, targets, seed=seed, threads=threads, **options)
                for member in getattr(model, "members", [model]):
                    member.metadata["dataset"] = dataset_info
                models[v] = model
                trainings.append({"fold": i, "test": list(test), "variant": v, "masked": True,
                                  "seconds": info["seconds"], "epochs": info["epochs"], "samples": info["samples"],
                                  "final_loss": info["losses"][-1], "curve": [[e + 1, None, x] for e, x in
                                                                              enumerate(info["losses"])]})
                continue
            shared = part if shared_garments is None else fields.select([g for g in train if g in shared_garments])
            model, info = train_model(shared, epochs=epochs, seed=seed, threads=threads,
                                      progress=curve_recorder(curve), **VARIANTS[v])
            model.metadata["dataset"] = dataset_info
            models[v] = model
            kept = ("seconds", "epochs", "threads", "final_loss", "final_masked_loss", "active_triangles",
                    "samples")
            trainings.append({"fold": i, "test": list(test), "variant": v,
                              "masked": VARIANTS[v].get("masked", True), **{k: info[k] for k in kept},
                              "garments": len(shared.garments), "curve": thin(curve, 100)})
        if any(m.placement in ("nearest", "mixed", "shrunk", "length_mixed") for m in methods):
            tables = tables or training_tables(ds, source, targets, list(train), fields=part)
            if "offset" not in tables:
                placement_tables(ds, source, targets, list(train), tables)
            models["nearest"] = nearest_garments(tables, targets, list(train), width=NEAREST_WIDTH)
            if "placement" in models:
                models["mixed"] = MixedPlacement(models["placement"], models["nearest"], LIBRARY_SHARE)
                models["shrunk"] = MixedPlacement(models["placement"], models["nearest"], LIBRARY_SHARE,
                                                  DISAGREEMENT_SHRINK)
                models["length_mixed"] = LengthMixed(models["mixed"], 1.0 / 3.0, up=_up_index(ds.up_axis))
        if any(m.placement == "length" for m in methods):
            models["length"] = LengthPlacement(up=_up_index(ds.up_axis))
        if on_models:
            on_models(i, models)
        step((i + 0.4) / len(folds), f"fold {i + 1}/{len(folds)} trained")
        for g in test:
            garment = ds.garment(g, source)
            prepared, prep_seconds = {}, {}
            for key in sorted({(m.interpolate, m.anchoring, m.energy) for m in methods if m.kind != "external"},
                              reverse=True):
                t = time.perf_counter()
                prepared[key] = prepare_garment(source_body, garment, interpolate=key[0], anchoring=key[1],
                                                energy=key[2])
                prep_seconds[key] = time.perf_counter() - t
            gi = fields.garments.index(g) if fields is not None and g in fields.garments else None
            for b in targets:
                body = bodies[b]
                ref = ds.garment(g, b)
                k = targets.index(b)
                oracle_placement = None
                if any(m.placement == "oracle" for m in methods):
                    binding = next(iter(prepared.values())).binding
                    oracle_placement = true_offsets(binding, source_body, body, ref.V)[0]

                def add(key, V, seconds, Q=None, **extra):
                    e = evaluate(garment, garment.with_vertices(V), body, reference=ref)
                    e.update(fold=i, garment=g, target=b, method=key, seconds=seconds, **extra)
                    if field_error and gi is not None and Q is not None:
                        e["field_rms"] = field_rms(Q, fields.deviation[gi, k].astype(np.float64),
                                                   fields.covered[gi])
                    rows.append(e)
                    if on_result:
                        on_result(g, b, key, garment, V)

                add(reference, ref.V, reference_seconds.get(g))
                for m in methods:
                    if m.kind == "external":
                        got = external.get(m.key, {}).get((g, b))
                        if got is not None:
                            add(m.key, got[0], got[1], seconds_reused=got[2])
                        continue
                    model, Q = None, None
                    key = (m.interpolate, m.anchoring, m.energy)
                    if m.kind == "model":
                        model = _field_source(m, models[m.variant], fields, gi, targets)
                        if field_error and getattr(model, "conditions_on_garment", False):
                            Q = model.body_field(b, garment, source_body, body)
                        elif field_error:
                            Q = model.body_field(b)
                    elif m.kind == "direct":
                        Q = body_fields.get(b)
                    placement = {None: None, "file": getattr(models.get("product"), "placement", None),
                                 "model": models.get("placement"), "nearest": models.get("nearest"),
                                 "mixed": models.get("mixed"), "shrunk": models.get("shrunk"),
                                 "length": models.get("length"), "length_mixed": models.get("length_mixed"),
                                 "oracle": oracle_placement}[m.placement]
                    r = transfer_garment(source_body, body, garment, method=m.kind, model=model, target=b,
                                         prepared=prepared[key], interpolate=m.interpolate,
                                         fix_penetration=m.fix_penetration, placement=placement)
                    add(m.key, r.V, prep_seconds[key] + r.seconds["total"], Q=Q,
                        seconds_reused=r.seconds["total"],
                        stages={s: v for s, v in r.seconds.items() if s != "total"})
        step((i + 1) / len(folds), f"fold {i + 1}/{len(folds)} evaluated")
    return {"rows": rows, "trainings": trainings, "read_seconds": read_seconds, "units": ds.units,
            "up_axis": ds.up_axis, "source": source, "targets": list(targets), "reference": reference,
            "folds": [{"train": list(tr), "test": list(te)} for tr, te in folds], "epochs": epochs}
