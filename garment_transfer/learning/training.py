"""Training the shared deformation model with torch, on the CPU (paper sect. 5).

Only this module imports torch; the trained model is written as plain arrays (``model.py``) and used
with numpy alone.

The network is the paper's: linear layers with sigmoid activations, an encoder from a garment's
embedded field (with the target's one-hot label, sect. 5.2) to a small latent code, a decoder back.
It learns the deviation from identity ``Q - I``, divided by its RMS per matrix entry. Our loss is the
mean squared error over the body triangles each garment covers (``masked=True``); the paper's loss,
over every triangle whatever the garment's extent, is ``masked=False``.

Two things make 1000 full-batch epochs at the paper's scale take seconds rather than minutes, without
changing what is learned:

* Triangles no training garment covers are left out of the network (masked mode): their loss is zero
  whatever the network outputs, and the model gives them the body's own deformation instead.
* The encoder's first layer is trained in the span of the training fields. Its gradient is always
  ``delta^T X``, a combination of the training fields, so writing ``W = A U^T`` with ``U`` an orthonormal
  basis of those fields (at most one direction per training sample) and training ``A`` follows exactly
  the same path on the training data as training ``W`` from the projection of the same initial weights.
  The saved model holds the full ``W``.
"""

from __future__ import annotations

import logging
import math
import os
import time

import numpy as np

from ..errors import Cancelled, DatasetError, SettingError
from ..files import check_outputs
from ..geometry.mesh import faces_hash
from ..version import __version__
from .dataset import build_training_fields, dataset_inputs, load_dataset
from .model import FORMAT, FORMAT_VERSION, SharedDeformationModel

log = logging.getLogger(__name__)

OPTIMIZERS = ("adam", "lbfgs", "scg")
DEFAULT_LR = {"adam": 3e-3, "lbfgs": 1.0, "scg": None}


def default_threads() -> int:
    """Torch threads for training: half the cores this process may use, at least 1, at most 4.

    An epoch is a few skinny matrix products over the decoder's large weight matrix: memory-bound, so
    hyper-threads and many cores buy little. Measured on a 2-core machine shared with other work
    (benchmarks/bench_training.py, 1000 epochs at the paper's scale): 46 s with 1 thread, 58 s with 2
    (82 s of CPU: the second thread mostly waits for a core). Pass ``threads`` to choose otherwise; the
    result is bit-for-bit the same for the same seed and thread count.
    """
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:
        n = os.cpu_count() or 1
    return max(1, min(n // 2, 4))


def normalisation_scale(dev, mask):
    """RMS of the deviation ``Q - I`` per matrix entry, over the covered triangles.

    Parameters
    ----------
    dev : (G,K,M,9) float
    mask : (G,M) bool or None
        None: every triangle counts.

    Returns
    -------
    scale : (9,) float64
        Never below 1e-6 (an all-identity dataset still gives a usable model).
    """
    d = dev.astype(np.float64)
    if mask is None:
        ms = np.mean(d ** 2, axis=(0, 1, 2))
    else:
        w = mask[:, None, :, None].astype(np.float64)
        ms = np.sum(w * d ** 2, axis=(0, 1, 2)) / max(np.sum(w) * d.shape[1], 1.0)
    return np.maximum(np.sqrt(ms), 1e-6)


def _uniform(gen, shape, fan_in):
    import torch

    bound = 1.0 / math.sqrt(fan_in)
    return (torch.rand(shape, generator=gen, dtype=torch.float32) * 2.0 - 1.0) * bound


class DeformationNet:
    """The encoder-decoder, with its gradient written by hand into persistent buffers.

    Every parameter is a view into one flat vector, and every gradient a view into another, so that
    Adam, L-BFGS and SCG share them and an epoch allocates nothing of the decoder's size: at the
    paper's scale the decoder's last layer (|M|*9 x latent) is nearly all the work, and fresh
    buffers of that size cost as much as the arithmetic.

    Parameters
    ----------
    basis : (D,r) tensor
        Orthonormal basis of the training rows (the encoder's first layer is ``input_scale A basis^T``,
        fed with ``coords = input_scale X basis``).
    D, K, latent : int
    hidden : list of int
    out_bias : (D,) tensor
        Initial bias of the last layer.
    gen : torch.Generator
    """

    def __init__(self, basis, D, K, latent, hidden, out_bias, gen, input_scale=1.0):
        import torch

        self.input_scale = input_scale
        enc_sizes = [*hidden, latent]
        dec_sizes = [latent + K, *reversed(hidden), D]
        W0 = _uniform(gen, (enc_sizes[0], D + K), D + K)
        init = [W0[:, :D] @ basis / input_scale, W0[:, D:].clone(), _uniform(gen, (enc_sizes[0],), D + K)]
        for i in range(1, len(enc_sizes)):
            fan = enc_sizes[i - 1]
            init += [_uniform(gen, (enc_sizes[i], fan), fan), _uniform(gen, (enc_sizes[i],), fan)]
        for i in range(1, len(dec_sizes)):
            fan = dec_sizes[i - 1]
            init += [_uniform(gen, (dec_sizes[i], fan), fan), _uniform(gen, (dec_sizes[i],), fan)]
        init[-1] = out_bias.clone()
        total = sum(t.numel() for t in init)
        self.flat = torch.empty(total)
        self.grad_flat = torch.zeros(total)
        self.params, self.grads, o = [], [], 0
        for t in init:
            n = t.numel()
            p = self.flat[o:o + n].view(t.shape)
            p.copy_(t)
            g = self.grad_flat[o:o + n].view(t.shape)
            p.grad = g
            self.params.append(p)
            self.grads.append(g)
            o += n
        self.A, self.Wc, self.b0 = self.params[:3]
        ne = 2 * (len(enc_sizes) - 1)
        self.enc = [tuple(self.params[3 + 2 * i:5 + 2 * i]) for i in range(ne // 2)]
        self.dec = [tuple(self.params[3 + ne + 2 * i:5 + ne + 2 * i]) for i in range(len(dec_sizes) - 1)]
        self._y = None

    def parameters(self):
        return list(self.params)

    def encode(self, coords, onehot, keep=None):
        import torch

        h = torch.sigmoid(torch.addmm(self.b0, coords, self.A.T).addmm_(onehot, self.Wc.T))
        if keep is not None:
            keep.append(h)
        for W, b in self.enc:
            h = torch.sigmoid(torch.addmm(b, h, W.T))
            if keep is not None:
                keep.append(h)
        return h

    def decode(self, z, onehot, keep=None, out=None):
        import torch

        h = torch.cat([z, onehot], dim=1)
        for i, (W, b) in enumerate(self.dec):
            if keep is not None:
                keep.append(h)
            if i < len(self.dec) - 1:
                h = torch.sigmoid(torch.addmm(b, h, W.T))
            else:
                h = torch.addmm(b, h, W.T, out=out) if out is not None else torch.addmm(b, h, W.T)
        return h

    def loss_and_grad(self, coords, onehot, X, mask, n):
        """Loss ``sum(mask * (y - X)^2) / n`` and its gradient, written into ``grad_flat``.

        Returns
        -------
        loss : float
        """
        import torch

        with torch.no_grad():
            enc_h, dec_in = [], []
            z = self.encode(coords, onehot, keep=enc_h)
            if self._y is None:
                self._y = torch.empty(X.shape)
            r = self.decode(z, onehot, keep=dec_in, out=self._y)
            r.sub_(X)
            if mask is not None:
                r.mul_(mask)
            flat = r.view(-1)
            loss = float(torch.dot(flat, flat)) / n
            scale = 2.0 / n
            # Backward through the decoder; delta is the gradient w.r.t. each layer's output,
            # carried unscaled and multiplied by 2/n where it is written.
            delta, s = r, scale
            gi = 3 + 2 * len(self.enc)
            for i in reversed(range(len(self.dec))):
                W, _ = self.dec[i]
                gW, gb = self.grads[gi + 2 * i], self.grads[gi + 2 * i + 1]
                u = dec_in[i]
                torch.addmm(gW, delta.T, u, beta=0.0, alpha=s, out=gW)
                torch.sum(delta, dim=0, out=gb)
                gb.mul_(s)
                delta = (delta @ W) * s
                s = 1.0
                if i > 0:
                    delta = delta * u * (1.0 - u)
            L = z.shape[1]
            delta = delta[:, :L]
            for j in reversed(range(len(enc_h))):
                h = enc_h[j]
                delta = delta * h * (1.0 - h)
                if j > 0:
                    W, _ = self.enc[j - 1]
                    gW, gb = self.grads[3 + 2 * (j - 1)], self.grads[4 + 2 * (j - 1)]
                    torch.mm(delta.T, enc_h[j - 1], out=gW)
                    torch.sum(delta, dim=0, out=gb)
                    delta = delta @ W
            torch.mm(delta.T, coords, out=self.grads[0])
            torch.mm(delta.T, onehot, out=self.grads[1])
            torch.sum(delta, dim=0, out=self.grads[2])
        return loss

    def state(self):
        return self.flat.clone()

    def load(self, state):
        self.flat.copy_(state)

    def export(self, basis):
        """Layer arrays for the model file: (out, in) float32 weights and biases."""
        import torch

        with torch.no_grad():
            W0 = torch.cat([(self.A * self.input_scale) @ basis.T, self.Wc], dim=1)
            enc = [(W0, self.b0)] + list(self.enc)
            arrays = {}
            for i, (W, b) in enumerate(enc):
                arrays[f"enc_W{i}"], arrays[f"enc_b{i}"] = W.numpy().copy(), b.numpy().copy()
            for i, (W, b) in enumerate(self.dec):
                arrays[f"dec_W{i}"], arrays[f"dec_b{i}"] = W.numpy().copy(), b.numpy().copy()
        return arrays


def _samples(dev, active, scale):
    """Stack (G,K,M,9) deviations into (G*K, D) normalised rows over the active triangles."""
    G, K = dev.shape[:2]
    X = (dev[:, :, active, :] / scale.astype(np.float32)).reshape(G * K, -1)
    onehot = np.zeros((G * K, K), np.float32)
    onehot[np.arange(G * K), np.tile(np.arange(K), G)] = 1.0
    return X.astype(np.float32), onehot


def _scg(fg, w, epochs, on_epoch):
    """Scaled conjugate gradient (Moller 1993), the paper's optimiser, on a flat parameter vector.

    Parameters
    ----------
    fg : callable(w) -> (loss float, grad tensor)
    w : (P,) tensor
        Start; updated in place.
    epochs : int
        Iterations (each costs two gradient evaluations).
    on_epoch : callable(epoch, loss) -> bool
        Returning True stops.
    """
    sigma0, lam, lam_bar = 1e-4, 1e-6, 0.0
    f, g = fg(w)
    r = -g
    p = r.clone()
    success = True
    n_restart = 50
    delta = 0.0
    for k in range(epochs):
        p2 = float(p @ p)
        if p2 == 0.0:
            break
        if success:
            sigma = sigma0 / math.sqrt(p2)
            _, g_s = fg(w + sigma * p)
            s = (g_s - g) / sigma
            delta = float(p @ s)
        delta_k = delta + (lam - lam_bar) * p2
        if delta_k <= 0:
            lam_bar = 2.0 * (lam - delta_k / p2)
            delta_k = -delta_k + lam * p2
            lam = lam_bar
        mu = float(p @ r)
        alpha = mu / delta_k
        w_new = w + alpha * p
        f_new, g_new = fg(w_new)
        Delta = 2.0 * delta_k * (f - f_new) / (mu * mu) if mu != 0 else 0.0
        if Delta >= 0:
            w.copy_(w_new)
            r_new = -g_new
            lam_bar = 0.0
            success = True
            if (k + 1) % n_restart == 0:
                p = r_new.clone()
            else:
                beta = (float(r_new @ r_new) - float(r_new @ r)) / mu
                p = r_new + beta * p
            f, g, r = f_new, g_new, r_new
            if Delta >= 0.75:
                lam = max(lam / 4.0, 1e-15)
        else:
            lam_bar = lam
            success = False
        if Delta < 0.25:
            lam = min(lam + delta_k * (1.0 - Delta) / p2, 1e100)
        if on_epoch(k, f):
            break
    return f


def train_model(fields, latent=30, epochs=1000, seed=0, masked=True, hidden=(), optimizer="adam",
                lr=None, holdout=None, patience=100, eval_every=10, threads=None, progress=None,
                progress_span=(0.0, 1.0)):
    """Train a shared deformation model on embedded garment fields.

    Parameters
    ----------
    fields : dataset.TrainingFields
        The training garments (G garments, K targets, M body triangles).
    latent : int
        Latent size (the paper: 30).
    epochs : int
        Full-batch optimiser steps (at most, with early stopping).
    seed : int
        Same seed, same data, same thread count: the same model, bit for bit.
    masked : bool
        True: loss over covered triangles only. False: the paper's loss over every body triangle (needs
        ``fields.raw_deviation``).
    hidden : sequence of int
        Sizes of hidden layers between the field and the latent code (mirrored in the decoder); empty
        (default) for the paper's scale, where each hidden unit costs as much as a latent one.
    optimizer : {"adam", "lbfgs", "scg"}
    lr : float, optional
        Learning rate (Adam, L-BFGS); default per optimiser.
    holdout : dataset.TrainingFields, optional
        Garments not trained on. Every ``eval_every`` epochs the field predicted for a new garment (the
        decoder at the mean latent of the training garments) is compared with theirs (masked MSE in
        normalised units); training stops after ``patience`` epochs without improvement and the best
        weights are kept.
    threads : int, optional
        Torch threads during training (default ``default_threads()``); restored afterwards.
    progress : callable(fraction, loss) -> bool, optional
        Called every epoch; returning True cancels (raises Cancelled; nothing is written).
    progress_span : (float, float)
        The fractions reported for the first and last epoch.

    Returns
    -------
    model : model.SharedDeformationModel
    info : dict
        JSON-serialisable: seconds, epochs, final_loss, final_masked_loss, best_validation_loss,
        stopped_early, threads, optimizer, lr, active_triangles, samples, loss_history.
    """
    if optimizer not in OPTIMIZERS:
        raise ValueError(f"optimizer must be one of {', '.join(OPTIMIZERS)}, got {optimizer!r}")
    if latent < 1 or epochs < 0:
        raise ValueError("latent must be >= 1 and epochs >= 0")
    if not masked and fields.raw_deviation is None:
        raise ValueError("the unmasked loss needs fields built with keep_raw=True")
    lr = DEFAULT_LR[optimizer] if lr is None else float(lr)
    threads = default_threads() if threads is None else max(1, int(threads))
    G, K, M = fields.deviation.shape[:3]
    dev = fields.deviation if masked else fields.raw_deviation
    active = fields.covered.any(axis=0) if masked else np.ones(M, bool)
    if not active.any():
        raise DatasetError(fields.source, "no training garment covers any body triangle")
    scale = normalisation_scale(dev, fields.covered if masked else None)
    X_np, onehot_np = _samples(dev, active, scale)
    t0 = time.perf_counter()
    arrays, run = _fit_network(fields, X_np, onehot_np, active, scale, latent=latent, epochs=epochs, seed=seed,
                               masked=masked, hidden=hidden, optimizer=optimizer, lr=lr, holdout=holdout,
                               patience=patience, eval_every=eval_every, threads=threads, progress=progress,
                               progress_span=progress_span)
    seconds = time.perf_counter() - t0
    settings = {"garments": list(fields.garments), "epochs": int(epochs), "epochs_run": run["epochs"],
                "optimizer": optimizer, "lr": lr, "seed": int(seed), "masked": bool(masked),
                "hidden": [int(h) for h in hidden], "threads": threads, "seconds": round(seconds, 3),
                "holdout": [] if holdout is None else list(holdout.garments), "patience": int(patience),
                "cover_distance": getattr(fields, "cover_distance", None)}
    model = _shared_model(fields, arrays, active, scale, latent, len(hidden), settings, run["losses"], X_np)
    losses = run["losses"]
    info = {"seconds": round(seconds, 3), "epochs": run["epochs"], "final_loss": losses["final"],
            "final_masked_loss": losses["final_masked"], "best_validation_loss": losses["best_validation"],
            "best_validation_epoch": losses["best_validation_epoch"], "stopped_early": run["early"],
            "threads": threads, "optimizer": optimizer, "lr": lr, "masked": bool(masked),
            "latent": int(latent), "garments": list(fields.garments), "targets": list(fields.targets),
            "active_triangles": int(active.sum()), "body_triangles": int(M), "samples": int(G * K),
            "loss_history": run["history"]}
    log.info("trained in %.1f s, %d epochs, loss %.4g", seconds, run["epochs"], losses["final"])
    return model, info


def _fit_network(fields, X_np, onehot_np, active, scale, *, latent, epochs, seed, masked, hidden, optimizer, lr,
                 holdout, patience, eval_every, threads, progress, progress_span):
    """The autoencoder fitted to the samples with torch (``train_model``'s settings).

    Returns
    -------
    arrays : dict
        The network's weights as numpy arrays (``DeformationNet.export``).
    run : dict
        ``epochs`` run, ``early`` (stopped early), ``history`` ([epoch, loss] pairs) and ``losses`` (final,
        final_masked, best_validation, best_validation_epoch).
    """
    import torch

    K = fields.deviation.shape[1]
    D = X_np.shape[1]
    old_threads = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        gen = torch.Generator().manual_seed(int(seed))
        X = torch.from_numpy(X_np)
        onehot = torch.from_numpy(onehot_np)
        # Orthonormal basis of the training rows: the encoder's first layer lives in their span.
        basis, rr = torch.linalg.qr(X.double().T)
        keep = torch.abs(torch.diagonal(rr)) > 1e-9 * max(float(torch.abs(rr).max()), 1e-300)
        basis = basis[:, keep].float().contiguous()
        # The encoder sees x / sqrt(D): inputs of unit size, so that the encoder's weights and the
        # decoder's have gradients of like scale (without it SCG and L-BFGS saturate the latent code
        # in their first steps and stall at the mean field; measured in benchmarks/bench_training.py).
        input_scale = 1.0 / math.sqrt(D)
        coords = X @ basis * input_scale
        if masked:
            mask_np = np.repeat(np.repeat(fields.covered[:, active], 9, axis=1), K, axis=0)
            mask = torch.from_numpy(mask_np.astype(np.float32))
            n_mask = float(mask.sum())
            out_bias = (X * mask).sum(0) / mask.sum(0).clamp(min=1.0)
        else:
            mask, n_mask = None, float(X.numel())
            out_bias = X.mean(0)
        net = DeformationNet(basis, D, K, latent, list(hidden), out_bias, gen, input_scale)

        def objective():
            return net.loss_and_grad(coords, onehot, X, mask, n_mask)

        val = _holdout_tensors(holdout, fields, active, scale, masked) if holdout is not None else None
        history, best = [], {"loss": math.inf, "epoch": -1, "state": None}
        lo, hi = progress_span
        stopped = {"early": False, "epochs": 0}

        def on_epoch(ep, loss):
            stopped["epochs"] = ep + 1
            if ep % max(1, epochs // 200) == 0 or ep == epochs - 1:
                history.append([ep + 1, float(loss)])
            if not math.isfinite(loss):
                raise FloatingPointError(f"training diverged at epoch {ep + 1} (loss {loss}); "
                                         "try a smaller learning rate")
            if val is not None and (ep % eval_every == 0 or ep == epochs - 1):
                v = _validation_loss(net, coords, onehot, val, K)
                if v < best["loss"]:
                    best.update(loss=v, epoch=ep + 1, state=net.state())
                elif ep + 1 - best["epoch"] >= patience:
                    stopped["early"] = True
                    return True
            if progress is not None and progress(lo + (hi - lo) * (ep + 1) / max(epochs, 1), float(loss)):
                raise Cancelled("training was cancelled")
            return False

        _optimise(optimizer, net, objective, epochs, lr, on_epoch)
        if best["state"] is not None:
            net.load(best["state"])
        with torch.no_grad():
            final = objective()
            y = net.decode(net.encode(coords, onehot), onehot)
            m = torch.from_numpy(np.repeat(np.repeat(fields.covered[:, active], 9, axis=1), K, axis=0)
                                 .astype(np.float32))
            final_masked = float((((y - X) * m) ** 2).sum() / m.sum().clamp(min=1.0))
        arrays = net.export(basis)
    finally:
        torch.set_num_threads(old_threads)
    losses = {"final": final, "final_masked": final_masked,
              "best_validation": None if best["state"] is None else best["loss"],
              "best_validation_epoch": None if best["state"] is None else best["epoch"]}
    return arrays, {"epochs": stopped["epochs"], "early": stopped["early"], "history": history, "losses": losses}


def _shared_model(fields, arrays, active, scale, latent, n_hidden, settings, losses, X_np):
    """The trained network's arrays and the model's metadata as one ``SharedDeformationModel``, with the
    training garments' latent codes per target and their mean (the code of a new garment)."""
    G, K = fields.deviation.shape[:2]
    body = fields.body
    arrays["active"] = active
    arrays["body_deviation"] = fields.body_deviation.astype(np.float32)
    arrays["mean_field"] = _mean_field(fields)
    arrays["latent_mean"] = np.zeros((K, latent))
    arrays["train_latents"] = np.zeros((G, K, latent))
    # The body itself, so that the model can serve garments dressed on other bodies (field_mapping).
    arrays["source_V"] = np.asarray(body.V, dtype=np.float64)
    arrays["source_face_vertices"] = np.asarray(body.face_vertices, dtype=np.int64)
    arrays["source_face_start"] = np.asarray(body.face_start, dtype=np.int64)
    metadata = {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "source": {"name": fields.source, "n_vertices": body.n_vertices, "n_faces": body.n_faces,
                   "n_triangles": body.n_triangles, "faces_hash": faces_hash(body)},
        "targets": list(fields.targets), "latent": int(latent),
        "encoder_layers": n_hidden + 1, "decoder_layers": n_hidden + 1,
        "normalisation": {"kind": "deviation_from_identity_over_rms", "scale": [float(s) for s in scale]},
        "uncovered": "body_deformation_gradient",
        "units": fields.units, "up_axis": fields.up_axis,
        "training": settings, "losses": losses,
        "created_with": f"garment_transfer {__version__}",
    }
    model = SharedDeformationModel(arrays, metadata, name="trained model")
    for k, t in enumerate(fields.targets):
        z = model.encode(X_np[k::K].astype(np.float64), t)
        arrays["train_latents"][:, k] = z
        arrays["latent_mean"][k] = z.mean(axis=0)
    return model


def _optimise(optimizer, net, objective, epochs, lr, on_epoch):
    """Run ``epochs`` full-batch steps; ``objective()`` returns the loss and fills the gradients."""
    import torch

    params = net.parameters()
    if optimizer == "adam":
        opt = torch.optim.Adam(params, lr=lr, fused=True)
        for ep in range(epochs):
            loss = objective()
            opt.step()
            if on_epoch(ep, loss):
                return
    elif optimizer == "lbfgs":
        opt = torch.optim.LBFGS(params, lr=lr, max_iter=1, history_size=10, line_search_fn="strong_wolfe")

        def closure():
            return torch.tensor(objective())

        for ep in range(epochs):
            loss = float(opt.step(closure))
            if on_epoch(ep, loss):
                return
    else:
        def fg(w):
            net.flat.copy_(w)
            loss = objective()
            return loss, net.grad_flat.clone()

        w = net.flat.clone()

        def at_w(ep, loss):
            # fg leaves the last trial point in the network, which SCG may have rejected
            net.flat.copy_(w)
            return on_epoch(ep, loss)

        _scg(fg, w, epochs, at_w)
        net.flat.copy_(w)


def _holdout_tensors(holdout, fields, active, scale, masked):
    import torch

    if list(holdout.targets) != list(fields.targets):
        raise ValueError("held-out fields must have the training targets")
    dev = holdout.deviation
    Xh, _ = _samples(dev, active, scale)
    mh = np.repeat(np.repeat(holdout.covered[:, active], 9, axis=1), dev.shape[1], axis=0)
    return torch.from_numpy(Xh), torch.from_numpy(mh.astype(np.float32))


def _validation_loss(net, coords, onehot, val, K):
    """Masked MSE between the field predicted for a new garment and the held-out garments' fields."""
    import torch

    Xh, mh = val
    with torch.no_grad():
        z = net.encode(coords, onehot)
        eye = torch.eye(K)
        zbar = torch.stack([z[k::K].mean(0) for k in range(K)])
        pred = net.decode(zbar, eye)
        Gh = Xh.shape[0] // K
        r = (pred.repeat(Gh, 1) - Xh) * mh
        return float((r * r).sum() / mh.sum().clamp(min=1.0))


def _mean_field(fields):
    """(K,M,9) float32: mean ``Q - I`` of the garments covering each triangle, else the body's."""
    w = fields.covered.astype(np.float64)[:, None, :, None]
    n = w.sum(axis=0)
    s = (fields.deviation.astype(np.float64) * w).sum(axis=0)
    out = np.where(n > 0, s / np.maximum(n, 1.0), fields.body_deviation)
    return out.astype(np.float32)


def check_training_settings(epochs, latent):
    """Raise SettingError unless epochs and latent are whole numbers >= 1."""

    for what, value in (("epochs", epochs), ("latent", latent)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise SettingError(what, f"{value!r} must be a whole number >= 1")


def train_from_dataset(dataset_dir, source, targets, garments=None, epochs=1000, latent=30, seed=0,
                       out=None, progress=None, **options):
    """Read a dataset folder, train a model and (optionally) write it.

    Parameters
    ----------
    dataset_dir : str or Path
        See ``dataset.load_dataset``.
    source : str
        Source body name.
    targets : list of str
        Target body names.
    garments : list of str, optional
        Training garments (default: every garment not in ``holdout``).
    epochs, latent, seed : int
        See ``train_model``.
    out : str or Path, optional
        Model file (.npz) to write, atomically, once training is complete.
    progress : callable(fraction, loss) -> bool, optional
        Reading the dataset reports fractions 0 to 0.1 with loss None; training 0.1 to 1.
        Returning True cancels (raises Cancelled; nothing is written).
    **options
        ``holdout`` (list of garment names, for early stopping), ``cover_distance``, and
        ``train_model``'s ``masked``, ``hidden``, ``optimizer``, ``lr``, ``patience``, ``eval_every``,
        ``threads``.

    Returns
    -------
    info : dict
        JSON-serialisable: ``train_model``'s info plus ``out``, ``source``, ``dataset``,
        ``read_seconds``.
    """

    holdout = list(options.pop("holdout", None) or [])
    cover_distance = options.pop("cover_distance", None)
    allowed = {"masked", "hidden", "optimizer", "lr", "patience", "eval_every", "threads"}
    unknown = set(options) - allowed
    if unknown:
        raise TypeError(f"unknown training options: {', '.join(sorted(unknown))}")
    check_training_settings(epochs=epochs, latent=latent)
    if out is not None:
        # Before the long work: a missing or read-only folder must not cost a whole training, and the
        # model file must not land on what the training reads.
        files, folders = dataset_inputs(dataset_dir)
        check_outputs([out], inputs=files, input_folders=folders, what="the model file")
    t0 = time.perf_counter()
    ds = load_dataset(dataset_dir)
    if isinstance(targets, str):
        targets = [t for t in targets.split(",") if t]
    garments = [g for g in ds.garments if g not in holdout] if garments is None else list(garments)
    overlap = set(garments) & set(holdout)
    if overlap:
        raise DatasetError(str(ds.folder),
                           f"garments both trained on and held out: {', '.join(sorted(overlap))}")
    read_progress = None
    if progress is not None:
        def read_progress(f):
            return progress(0.1 * f, None)
    fields = build_training_fields(ds, source, targets, garments + holdout, cover_distance,
                                   keep_raw=not options.get("masked", True), progress=read_progress)
    read_seconds = time.perf_counter() - t0
    train_fields = fields.select(garments)
    held = fields.select(holdout) if holdout else None
    model, info = train_model(train_fields, latent=latent, epochs=epochs, seed=seed, holdout=held,
                              progress=progress, progress_span=(0.1, 1.0), **options)
    model.metadata["dataset"] = {"folder": os.path.basename(os.path.abspath(os.fspath(dataset_dir))),
                                 "units": ds.units, "up_axis": ds.up_axis}
    if out is not None:
        model.save(out)
        info["out"] = os.fspath(out)
    else:
        info["out"] = None
    info.update(source=source, dataset=os.fspath(dataset_dir), read_seconds=round(read_seconds, 3))
    return info
