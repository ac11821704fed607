"""Training of the garment-conditioned fit model (``garment_model.py``) with torch.

Every covered source body triangle of every training garment and target is one sample: its garment
and target features in, the garment's embedded deformation minus the body's own out (normalised).
The samples are gathered by index from per-garment and per-target feature tables, so memory grows
with garments + targets, not with their product.
"""

from __future__ import annotations

import logging
import time

import numpy as np

from ..errors import Cancelled, DatasetError
from ..files import check_outputs
from ..geometry.binding import bind
from ..geometry.embedding import body_scale
from ..geometry.mesh import faces_hash
from .dataset import build_training_fields, dataset_inputs, load_dataset
from .garment_model import (
    FORMAT,
    FORMAT_VERSION,
    GARMENT_FEATURES,
    NEIGHBOURHOOD_SHARES,
    GarmentFitModel,
    garment_features,
    target_features,
)
from .model_files import save_garment_fit_bundle
from .placement import (
    BASE_FORMAT_VERSION,
    BODY_OFFSET_SHARES,
    CONTEXT_COLUMNS,
    CONTEXT_SHARES,
    LIBRARY_FORMAT,
    LIBRARY_FORMAT_VERSION,
    LIBRARY_SHARE,
    SIMILARITY_WIDTH,
    SMOOTHING_SHARE,
    NearestGarments,
    PlacementEnsemble,
    PlacementModel,
    body_offset_features,
    bound_counts,
    garment_contexts,
    mean_offsets,
    similarity_features,
    smooth_on_body,
    true_offsets,
)
from .placement import FORMAT as PFORMAT
from .placement import FORMAT_VERSION as PVERSION
from .training import default_threads

log = logging.getLogger(__name__)


def training_tables(dataset, source, targets, garments, fields=None):
    """The feature tables and targets of a training set.

    Parameters
    ----------
    dataset : Dataset or str or Path
    source : str
    targets, garments : list of str
    fields : dataset.TrainingFields, optional
        Already built for these garments and targets (in this order).

    Returns
    -------
    dict
        ``garment_X (G,M,12)``, ``covered (G,M) bool``, ``target_X (K,M,9*(1+r))``, ``deviation (G,K,M,9)``
        (the garment's ``Q - I``), ``body_deviation (K,M,9)``, ``bodies (K,nb,3)``, ``body`` (the source
        Mesh).
    """
    ds = dataset if hasattr(dataset, "garment") else load_dataset(dataset)
    if fields is None:
        fields = build_training_fields(ds, source, targets, garments)
    if list(fields.garments) != list(garments) or list(fields.targets) != list(targets):
        raise DatasetError(str(ds.folder), "the training fields were built for other garments or targets")
    body = ds.body(source)
    gx, cov = [], []
    for g in garments:
        m = ds.garment(g, source)
        X, c = garment_features(body.V, body.F, m.V, m.F, fields.cover_distance)
        gx.append(X.astype(np.float32))
        cov.append(c & fields.covered[garments.index(g)])
    bodies = [ds.body(t).V for t in targets]
    tx = [target_features(body.V, V, body.F)[0].astype(np.float32) for V in bodies]
    return {"garment_X": np.stack(gx), "covered": np.stack(cov), "target_X": np.stack(tx),
            "deviation": fields.deviation, "body_deviation": fields.body_deviation,
            "bodies": np.stack(bodies).astype(np.float32), "body": body}


def train_garment_model(tables, targets, hidden=(64, 64), epochs=8, batch=8192, lr=3e-3, use_label=True,
                        garment_inputs=True, seed=0, threads=None, progress=None):
    """Fit the per-triangle network on ``training_tables``.

    Parameters
    ----------
    tables : dict
        From ``training_tables``.
    targets : list of str
        Target labels, in the tables' order.
    hidden : tuple of int
        Hidden layer widths (tanh).
    epochs : int
        Passes over every sample (Adam, minibatches, learning rate decaying to a tenth).
    batch : int
    lr : float
    use_label : bool
        Condition on the target's label weights as well as on its body's deformation.
    garment_inputs : bool
        False withholds the garment's distance and direction from the body (coverage and position
        are kept): what the garment features give, measured.
    seed : int
        Same seed, data and threads: the same model.
    threads : int, optional
        torch threads.
    progress : callable(fraction, loss) -> bool, optional
        Called after each epoch; returning True cancels (raises Cancelled).

    Returns
    -------
    model : GarmentFitModel
    info : dict
        ``seconds``, ``samples``, ``epochs``, ``losses`` (per epoch, normalised MSE).
    """
    import torch

    t0 = time.perf_counter()
    if threads:
        torch.set_num_threads(int(threads))
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    GX = torch.from_numpy(np.array(tables["garment_X"], dtype=np.float32))
    if not garment_inputs:
        GX[:, :, 1:9] = 0.0
    TX = torch.from_numpy(np.ascontiguousarray(tables["target_X"]))
    dev = tables["deviation"]
    bdev = tables["body_deviation"]
    G, K = dev.shape[0], dev.shape[1]
    g_idx, a_idx = np.nonzero(tables["covered"])
    gi = np.repeat(g_idx, K)
    ai = np.repeat(a_idx, K)
    ki = np.tile(np.arange(K), len(g_idx))
    Y = (dev[gi, ki, ai] - bdev[ki, ai]).astype(np.float32)
    net, mean, std, out_scale, losses = _fit(GX, TX, gi, ki, ai, Y, K, hidden, epochs, batch, lr, use_label, gen,
                                             progress, "garment model")
    arrays, metadata = _package(net, mean, std, out_scale, losses, tables, targets, hidden, use_label,
                                garment_inputs, epochs, batch, lr, seed, len(Y), G, t0)
    metadata.update(format=FORMAT, format_version=FORMAT_VERSION)
    info = {"seconds": metadata["training"]["seconds"], "samples": len(Y), "epochs": epochs, "losses": losses}
    return GarmentFitModel(arrays, metadata, "garment fit model"), info


def _package(net, mean, std, out_scale, losses, tables, targets, hidden, use_label, garment_inputs, epochs, batch,
             lr, seed, n, G, t0):
    """The arrays and metadata (all but the format) of a trained per-triangle network."""
    import torch

    linear = [m for m in net if isinstance(m, torch.nn.Linear)]
    arrays = {"input_mean": mean.double().numpy(), "input_std": std.double().numpy(),
              "label_bodies": tables["bodies"].astype(np.float32)}
    for i, m in enumerate(linear):
        arrays[f"W{i}"] = m.weight.detach().numpy().astype(np.float32)
        arrays[f"b{i}"] = m.bias.detach().double().numpy()
    body = tables["body"]
    seconds = time.perf_counter() - t0
    metadata = {"targets": list(targets),
                "layers": len(linear), "hidden": list(hidden), "use_label": bool(use_label),
                "garment_inputs": bool(garment_inputs),
                "output_scale": out_scale.tolist(), "garment_features": list(GARMENT_FEATURES),
                "neighbourhood_shares": list(NEIGHBOURHOOD_SHARES), "cover_distance": None,
                "source": {"name": body.name, "n_vertices": body.n_vertices, "n_faces": body.n_faces,
                           "n_triangles": body.n_triangles, "faces_hash": faces_hash(body)},
                "training": {"epochs": epochs, "batch": batch, "lr": lr, "seed": seed, "samples": int(n),
                             "garments": int(G), "seconds": round(seconds, 2),
                             "final_loss": losses[-1] if losses else None}}
    return arrays, metadata


def placement_tables(dataset, source, targets, garments, tables, length=None, context_shares=None):
    """The training targets of the placement model: every garment's true placement on every target.

    Parameters
    ----------
    dataset : Dataset or str or Path
    source : str
    targets, garments : list of str
        In the order of ``tables``.
    tables : dict
        ``training_tables`` of the same garments and targets; ``offset (G,K,M,3)`` (the unrotated
        smoothed offsets, ``placement.true_offsets``) and ``bound (G,M)`` (bound garment vertices per
        triangle) are added to it.
    length : float, optional
        Smoothing length (default ``placement.SMOOTHING_SHARE`` of the body scale).
    context_shares : sequence of float, optional
        ``placement.garment_context``'s (default ``placement.CONTEXT_SHARES``); ``garment_context
        (G,M,3c)`` and ``context_shares`` are added too.

    Returns
    -------
    dict
        ``tables``, with those entries added.
    """

    ds = dataset if hasattr(dataset, "garment") else load_dataset(dataset)
    body = tables["body"]
    bodies = [ds.body(t) for t in targets]
    G, K, M = len(garments), len(targets), body.n_triangles
    offset = np.zeros((G, K, M, 3), np.float32)
    bound = np.zeros((G, M), np.float32)
    length = SMOOTHING_SHARE * body_scale(body.V) if length is None else float(length)
    for g, name in enumerate(garments):
        garment = ds.garment(name, source)
        binding = bind(garment.V, body.V, body.F)
        # true_offsets' smoothing, once for every target: its matrix depends on the garment's binding alone.
        raw = [true_offsets(binding, body, bodies[k], ds.garment(name, t).V, 0.0)[1] for k, t in enumerate(targets)]
        bound[g] = bound_counts(binding, M)
        y = smooth_on_body(np.concatenate(raw, axis=1), bound[g], body.V, body.F, length)
        offset[g] = y.reshape(M, K, 3).transpose(1, 0, 2)
    shares = tuple(CONTEXT_SHARES if context_shares is None else context_shares)
    tables["garment_context"] = np.stack(garment_contexts(body.V, body.F, tables["garment_X"], shares)
                                         ).astype(np.float32)
    tables["context_shares"] = list(shares)
    tables["offset"] = offset
    tables["bound"] = bound
    return tables


def train_placement_model(tables, targets, hidden=(64, 64), epochs=30, batch=8192, lr=1e-2, use_label=True,
                          garment_inputs=True, seed=0, threads=None, length_share=None, body_offset=False,
                          schedule="exp", weight_decay=0.0, weighted=False, residual=False, progress=None):
    """Fit the placement model (``placement.PlacementModel``) on ``placement_tables``.

    Every body triangle a garment vertex is bound to, for every target, is one sample: the garment's
    and target's features in, its smoothed offset in the triangle's unrotated frame out. Parameters as
    ``train_garment_model``'s (more passes and a larger step by default: there are as many samples as
    bound triangles, a tenth of the field model's); ``length_share``: the smoothing of the predictions
    (default that of the targets, ``placement.SMOOTHING_SHARE``); ``body_offset``: also the target's
    offset from the source body (``placement.body_offset_features``) as an input; ``schedule`` and
    ``weight_decay``: ``_fit``'s; ``weighted``: each sample's squared error weighted by the garment points
    bound to its triangle (default: every bound triangle alike); ``residual``: the network learns the offset
    less the training garments' mean offset on each triangle and target (``placement.mean_offsets``), which
    the model keeps (``offset_base``, format version 2) and adds back.

    Returns
    -------
    model : placement.PlacementModel
    info : dict
        ``seconds``, ``samples``, ``epochs``, ``losses``.
    """
    import torch

    t0 = time.perf_counter()
    if threads:
        torch.set_num_threads(int(threads))
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)

    own = np.array(tables["garment_X"], dtype=np.float32)
    context = np.array(tables["garment_context"], dtype=np.float32)
    if not garment_inputs:
        own[:, :, 1:9] = 0.0
        # What the context is of zeroed distances: only the coverage is left.
        context.reshape(*context.shape[:2], -1, CONTEXT_COLUMNS)[..., 1:] = 0.0
    GX = torch.from_numpy(np.concatenate([own, context], axis=2))
    TX = np.asarray(tables["target_X"], dtype=np.float32)
    if body_offset:
        body = tables["body"]
        TX = np.concatenate([TX, np.stack([body_offset_features(body.V, V, body.F, BODY_OFFSET_SHARES)
                                           for V in tables["bodies"]]).astype(np.float32)], axis=2)
    TX = torch.from_numpy(np.ascontiguousarray(TX))
    off = tables["offset"]
    G, K = off.shape[0], off.shape[1]
    g_idx, a_idx = np.nonzero(tables["bound"] > 0)
    gi = np.repeat(g_idx, K)
    ai = np.repeat(a_idx, K)
    ki = np.tile(np.arange(K), len(g_idx))
    Y = off[gi, ki, ai].astype(np.float32)
    base = None
    if residual:
        base = mean_offsets(off, tables["bound"]).astype(np.float32)
        Y = Y - base[ki, ai]
    sample_weight = tables["bound"][gi, ai] if weighted else None
    net, mean, std, out_scale, losses = _fit(GX, TX, gi, ki, ai, Y, K, hidden, epochs, batch, lr, use_label, gen,
                                             progress, "placement model", schedule=schedule,
                                             weight_decay=weight_decay, sample_weight=sample_weight)
    arrays, metadata = _package(net, mean, std, out_scale, losses, tables, targets, hidden, use_label,
                                garment_inputs, epochs, batch, lr, seed, len(Y), G, t0)
    if base is not None:
        arrays["offset_base"] = base
    metadata.update(format=PFORMAT, format_version=PVERSION if base is None else BASE_FORMAT_VERSION,
                    context_shares=list(tables["context_shares"]),
                    smoothing_share=float(SMOOTHING_SHARE if length_share is None else length_share))
    metadata["training"].update(schedule=schedule, weight_decay=float(weight_decay), weighted=bool(weighted),
                                residual=bool(residual))
    if body_offset:
        metadata["body_offset_shares"] = list(BODY_OFFSET_SHARES)
    info = {"seconds": metadata["training"]["seconds"], "samples": len(Y), "epochs": epochs, "losses": losses}
    return PlacementModel(arrays, metadata, "placement model"), info

def nearest_garments(tables, targets, garments=None, width=None, length_share=None):
    """The nearest garments' placement (``placement.NearestGarments``) of ``placement_tables``.

    Every training garment's placement on every target and its ``placement.similarity_features``, kept on
    the body triangles it is bound to; nothing is trained.

    Parameters
    ----------
    tables : dict
        ``placement_tables``' (``garment_X``, ``garment_context``, ``context_shares``, ``offset``, ``bound``,
        ``bodies``, ``body``).
    targets : list of str
        In the order of ``tables``.
    garments : list of str, optional
        The training garments' names, in the order of ``tables`` (kept in the metadata).
    width : float, optional
        ``placement.SIMILARITY_WIDTH`` by default.
    length_share : float, optional
        The smoothing of its predictions (default ``placement.SMOOTHING_SHARE``).

    Returns
    -------
    placement.NearestGarments
    """

    GX, context = tables["garment_X"], tables["garment_context"]
    offset, bound = tables["offset"], tables["bound"]
    G = offset.shape[0]
    names = [f"garment {g}" for g in range(G)] if garments is None else list(garments)
    if len(names) != G or len(targets) != offset.shape[1]:
        raise ValueError(f"{len(names)} garment names and {len(targets)} targets for placement tables of "
                         f"{G} garments and {offset.shape[1]} targets")
    tri, gar, feats, offs, wts = [], [], [], [], []
    for g in range(G):
        idx = np.nonzero(bound[g] > 0)[0]
        tri.append(idx)
        gar.append(np.full(len(idx), g))
        feats.append(similarity_features(GX[g][idx], context[g][idx]))
        offs.append(offset[g][:, idx])
        wts.append(bound[g][idx])
    features = np.concatenate(feats)
    if features.shape[0] == 0:
        raise ValueError("no training garment is bound to the body")
    scale = features.std(axis=0)
    scale[~(scale > 1e-9)] = 1.0
    body = tables["body"]
    arrays = {"triangles": np.concatenate(tri).astype(np.int32), "garment": np.concatenate(gar).astype(np.int32),
              "features": features.astype(np.float32), "offsets": np.concatenate(offs, axis=1).astype(np.float32),
              "weights": np.concatenate(wts).astype(np.float32), "feature_scale": scale.astype(np.float32),
              "label_bodies": np.asarray(tables["bodies"], dtype=np.float32)}
    metadata = {"format": LIBRARY_FORMAT, "format_version": LIBRARY_FORMAT_VERSION, "targets": list(targets),
                "source": {"name": body.name, "n_vertices": body.n_vertices, "n_faces": body.n_faces,
                           "n_triangles": body.n_triangles, "faces_hash": faces_hash(body)},
                "cover_distance": None, "context_shares": list(tables["context_shares"]),
                "smoothing_share": float(SMOOTHING_SHARE if length_share is None else length_share),
                "similarity_width": float(SIMILARITY_WIDTH if width is None else width), "garments": names}
    return NearestGarments(arrays, metadata, "nearest garments placement")


def train_placement_ensemble(tables, targets, members=None, seed=0, progress=None, **options):
    """``train_placement_model`` ``members`` times, with seeds ``seed``, ``seed + 1``, ...: their mean
    (``placement.PlacementEnsemble``) predicts with less of a single network's variance.

    Parameters
    ----------
    tables, targets
        As ``train_placement_model``'s.
    members : int, optional
        How many (>= 1; default ``PLACEMENT_MEMBERS``). One: that model itself.
    seed : int
        The first member's; the others' follow.
    progress : callable(fraction, loss) -> bool, optional
        Over all the members (0 to 1).
    **options
        ``train_placement_model``'s other arguments, the same for every member.

    Returns
    -------
    model : placement.PlacementModel or placement.PlacementEnsemble
    info : dict
        ``seconds`` (all members), ``samples``, ``epochs``, ``members``, ``losses`` (the members' mean per
        pass).
    """

    n = PLACEMENT_MEMBERS if members is None else members
    if int(n) != n or n < 1:
        raise ValueError(f"the placement needs a whole number >= 1 of members, got {n}")
    n = int(n)
    trained = []
    for i in range(n):
        step = None if progress is None else (lambda f, loss, i=i: progress((i + f) / n, loss))
        trained.append(train_placement_model(tables, targets, seed=seed + i, progress=step, **options))
    infos = [t[1] for t in trained]
    info = {"seconds": round(sum(x["seconds"] for x in infos), 2), "samples": infos[0]["samples"],
            "epochs": infos[0]["epochs"], "members": n,
            "losses": [float(np.mean(v)) for v in zip(*(x["losses"] for x in infos))]}
    if n == 1:
        return trained[0][0], info
    return PlacementEnsemble([t[0] for t in trained]), info


def _fit(GX, TX, gi, ki, ai, Y, K, hidden, epochs, batch, lr, use_label, gen, progress, what, schedule="exp",
         weight_decay=0.0, sample_weight=None):
    """The per-triangle network fitted to samples ``Y (n,c)`` at (garment gi, target ki, triangle ai).

    ``schedule``: the learning rate's decay over the passes, ``exp`` (to a tenth, geometrically) or
    ``cosine`` (half a cosine, to a hundredth); ``weight_decay``: decoupled weight decay (AdamW) when > 0;
    ``sample_weight (n,)``: the samples' weights in the mean squared error (default equal).
    """
    import torch

    if schedule not in SCHEDULES:
        raise ValueError(f"unknown learning rate schedule {schedule!r}: one of {', '.join(SCHEDULES)}")
    out_scale = np.maximum(Y.std(axis=0), 1e-3).astype(np.float64)
    Y = torch.from_numpy(Y / out_scale.astype(np.float32))
    sw = None
    if sample_weight is not None:
        sw = np.asarray(sample_weight, dtype=np.float64)
        sw = torch.from_numpy((sw / sw.mean()).astype(np.float32))
    gi, ki, ai = (torch.from_numpy(x.astype(np.int64)) for x in (gi, ki, ai))
    eye = torch.eye(K)

    def inputs(sel):
        parts = [GX[gi[sel], ai[sel]], TX[ki[sel], ai[sel]]]
        if use_label:
            parts.append(eye[ki[sel]])
        return torch.cat(parts, dim=1)

    n = len(Y)
    probe = inputs(torch.randperm(n, generator=gen)[:min(n, 200_000)])
    mean = probe.mean(0)
    std = probe.std(0).clamp_min(1e-3)
    sizes = [probe.shape[1], *hidden, Y.shape[1]]
    layers = []
    for i in range(len(sizes) - 1):
        layers.append(torch.nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(torch.nn.Tanh())
    net = torch.nn.Sequential(*layers)
    if weight_decay > 0:
        opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
    else:
        opt = torch.optim.Adam(net.parameters(), lr=lr)
    steps = max(epochs * ((n + batch - 1) // batch), 1)
    if schedule == "cosine":
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.01 + 0.99 * 0.5 * (1 + np.cos(np.pi * s / steps)))
    else:
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.1 ** (s / steps))
    losses = []
    for ep in range(epochs):
        perm = torch.randperm(n, generator=gen)
        total = 0.0
        for s in range(0, n, batch):
            sel = perm[s:s + batch]
            pred = net((inputs(sel) - mean) / std)
            if sw is None:
                loss = torch.mean((pred - Y[sel]) ** 2)
            else:
                loss = torch.mean(sw[sel][:, None] * (pred - Y[sel]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss.detach()) * len(sel)
        losses.append(total / n)
        log.info("%s epoch %d/%d: loss %.4f", what, ep + 1, epochs, losses[-1])
        if progress is not None and progress((ep + 1) / epochs, losses[-1]):
            raise Cancelled(f"training of the {what} was cancelled")
    return net, mean, std, out_scale, losses


#: Learning rate schedules of ``_fit``.
SCHEDULES = ("exp", "cosine")
#: Passes of ``train_garment_fit_from_dataset`` over the field model's and the placement model's samples:
#: those of the measured combination (lab/notes/garment-model-study.md: 3 and 30).
FIELD_EPOCHS = 3
PLACEMENT_EPOCHS = 30
#: Placement models averaged (``train_placement_ensemble``). Chosen among 1, 3 and 5 on held-out training
#: garments (the demo's validation fold, pear, half the field): drape error 0.412, 0.4035 and 0.4036
#: (lab/notes/garment-model-study.md).
PLACEMENT_MEMBERS = 3
#: Whether the placement networks learn the offset less the training garments' mean offset per triangle
#: (``train_placement_model``'s ``residual``). Chosen on held-out training garments (the demo's validation
#: fold, pear, half the field, 3 members; mean of 3 seed sets): drape error 0.406 -> 0.390, against 0.393
#: for wider layers and 0.398 for more passes; on the test garments 0.352 -> 0.313 (lab/notes/garment-model-study.md).
PLACEMENT_RESIDUAL = True


def train_garment_fit_from_dataset(dataset_dir, source, targets, garments=None, epochs=FIELD_EPOCHS,
                                   placement_epochs=PLACEMENT_EPOCHS, placement=True, seed=0, out=None,
                                   progress=None, threads=None, placement_members=PLACEMENT_MEMBERS,
                                   placement_residual=PLACEMENT_RESIDUAL, library_share=None):
    """Read a dataset folder, train the garment fit model and its learned placement, and write both to
    one file (``model_files.save_garment_fit_bundle``).

    Parameters
    ----------
    dataset_dir : str or Path
        See ``dataset.load_dataset``.
    source : str
        Source body name.
    targets : list of str
        Target body names.
    garments : list of str, optional
        Training garments (default: all).
    epochs : int
        Passes over the field model's samples.
    placement_epochs : int
        Passes over the placement model's samples.
    placement : bool
        Train the learned placement too.
    seed : int
    out : str or Path, optional
        Model file (.npz) to write, atomically, once both are trained.
    progress : callable(fraction, loss) -> bool, optional
        Reading 0 to 0.1 (loss None), the field model to 0.5 (or 1), the placement to 1. Returning True
        cancels (raises Cancelled; nothing is written).
    threads : int, optional
        torch threads (default ``training.default_threads()``).
    placement_members : int
        Placement models trained (seeds ``seed``, ``seed + 1``, ...) and averaged
        (``train_placement_ensemble``).
    placement_residual : bool
        Each placement network learns the offset less the training garments' mean offset per triangle
        (``train_placement_model``'s ``residual``; the file's placement is then of format version 2).
    library_share : float, optional
        The share of the nearest garments' placement (``nearest_garments``) mixed with the networks'
        (``placement.MixedPlacement``; default ``placement.LIBRARY_SHARE``); 0 leaves it out of the file.

    Returns
    -------
    info : dict
        JSON-serialisable: ``kind`` ("garment"), ``out``, ``source``, ``targets``, ``garments``,
        ``dataset``, ``threads``, ``read_seconds``, ``seconds``, and per part (``field``, ``placement`` or None) its
        ``epochs``, ``samples``, ``seconds`` and ``final_loss`` (the placement's also ``members``).
    """
    import os



    threads = default_threads() if threads is None else max(1, int(threads))
    library_share = LIBRARY_SHARE if library_share is None else float(library_share)
    if not 0.0 <= library_share <= 1.0:
        raise ValueError(f"library_share must be between 0 and 1, got {library_share}")
    if isinstance(targets, str):
        targets = [t for t in targets.split(",") if t]
    for what, n in (("epochs", epochs), ("placement_epochs", placement_epochs),
                    ("placement_members", placement_members)):
        if int(n) != n or n < 1:
            raise ValueError(f"{what} must be a whole number >= 1, got {n}")
    if out is not None:
        # Before the long work, and never onto what the training reads.
        files, folders = dataset_inputs(dataset_dir)
        check_outputs([out], inputs=files, input_folders=folders, what="the model file")
    t0 = time.perf_counter()
    ds = load_dataset(dataset_dir)
    garments = list(ds.garments) if garments is None else list(garments)
    targets = list(targets)
    read_progress = None if progress is None else (lambda f: progress(0.1 * f, None))
    fields = build_training_fields(ds, source, targets, garments, progress=read_progress)
    tables = training_tables(ds, source, targets, garments, fields=fields)
    read_seconds = time.perf_counter() - t0
    end = 0.5 if placement else 1.0

    def span(lo, hi):
        return None if progress is None else (lambda f, loss: progress(lo + (hi - lo) * f, loss))

    field_model, field_info = train_garment_model(tables, targets, epochs=int(epochs), seed=seed, threads=threads,
                                                  progress=span(0.1, end))
    placement_model, placement_info, library = None, None, None
    if placement:
        placement_tables(ds, source, targets, garments, tables)
        placement_model, placement_info = train_placement_ensemble(tables, targets, int(placement_members),
                                                                   seed=seed, progress=span(0.5, 1.0),
                                                                   epochs=int(placement_epochs), threads=threads,
                                                                   residual=bool(placement_residual))
        if library_share > 0:
            library = nearest_garments(tables, targets, garments)
    dataset_info = {"folder": os.path.basename(os.path.abspath(os.fspath(dataset_dir))), "units": ds.units,
                    "up_axis": ds.up_axis}
    placed = [] if placement_model is None else getattr(placement_model, "members", [placement_model])
    for m in [field_model, *placed]:
        m.metadata["dataset"] = dataset_info
    if out is not None:

        save_garment_fit_bundle(out, field_model, placement_model, dataset=dataset_info, library=library,
                                library_share=library_share)

    def part(info):
        return None if info is None else {"epochs": info["epochs"], "samples": int(info["samples"]),
                                          "seconds": info["seconds"], "final_loss": float(info["losses"][-1]),
                                          **({"members": info["members"]} if "members" in info else {})}

    return {"kind": "garment", "out": None if out is None else os.fspath(out), "source": source,
            "targets": targets, "garments": garments, "dataset": os.fspath(dataset_dir), "threads": threads,
            "read_seconds": round(read_seconds, 3), "seconds": round(time.perf_counter() - t0, 2),
            "field": part(field_info), "placement": part(placement_info),
            "library": None if library is None else {"share": library_share,
                                                     "entries": int(library.arrays["triangles"].shape[0])}}
