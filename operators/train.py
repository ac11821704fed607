"""Train a model from a dataset folder (the shared deformation model, or the garment fit model with its
placement), without freezing Blender.

``invoke`` runs modally: a timer advances a step generator, the window shows progress, Esc cancels.
``execute`` drains the same generator, so scripts, tests and background mode take the same path.
The training itself runs in a worker thread (torch releases the GIL while it computes); the generator
only reports its progress and passes a cancel request on.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time

import bpy

from .models import refresh_found_model
from .reporting import ModalSteps, report_failure

TORCH_PIN = "torch==2.13.0"


def torch_missing_message():
    """None when torch can be imported; otherwise how to install it."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return (f"Training needs PyTorch, which this Python does not have. Install it with: "
                f"\"{sys.executable}\" -m pip install {TORCH_PIN} (transfer works without it)")
    return None


class TrainingRun:
    """Training in a worker thread; ``steps()`` yields its progress (a fraction) until it ends."""

    def __init__(self, train_call):
        self._call = train_call
        self.fraction = 0.0
        self.cancel_requested = False
        self.result = None
        self.error = None
        self._thread = threading.Thread(target=self._run, name="garment-transfer-training",
                                        daemon=True)

    def _progress(self, fraction, _loss=None):
        self.fraction = float(fraction)
        return self.cancel_requested

    def _run(self):
        try:
            self.result = self._call(self._progress)
        except BaseException as exc:
            self.error = exc

    def steps(self):
        """Yield the progress fraction while training runs; then raise its error or return its result."""
        self._thread.start()
        try:
            while self._thread.is_alive():
                yield self.fraction
        finally:
            if self._thread.is_alive():
                self.cancel_requested = True
                self._thread.join()
        if self.error is not None:
            raise self.error
        return self.result


def training_output(settings):
    """The model file to write, and the training numbers, checked: a missing or read-only folder must
    not cost a whole training (nor an install of torch), and the file must not land on the dataset the
    training reads (the core's one check of outputs against inputs). Returns the path."""
    from ..garment_transfer import check_outputs, check_training_settings, dataset_inputs

    out = bpy.path.abspath(settings.train_output)
    if not out.lower().endswith(".npz") and not os.path.isdir(out):
        out += ".npz"
    files, folders = dataset_inputs(bpy.path.abspath(settings.dataset_path))
    check_outputs([out], inputs=files, input_folders=folders, what="Save Model As")
    check_training_settings(epochs=settings.train_epochs, latent=settings.train_latent)
    return out


def training_plan(settings):
    """Dataset, source body, targets and output file from the panel's settings (checked).

    Returns
    -------
    dict
        Keyword arguments for ``training.train_from_dataset`` (``progress`` excepted).
    """
    from ..garment_transfer import DatasetError, load_dataset

    out = training_output(settings)
    folder = bpy.path.abspath(settings.dataset_path)
    dataset = load_dataset(folder)
    source = settings.dataset_source.strip() or dataset.bodies[0]
    if source not in dataset.bodies:
        raise DatasetError(folder, f"has no body {source!r}; it has {', '.join(dataset.bodies)}")
    targets = [t.strip() for t in settings.dataset_targets.split(",") if t.strip()]
    targets = targets or [b for b in dataset.bodies if b != source]
    if not targets:
        raise DatasetError(folder, f"has no body besides the source body {source!r} to train for")
    held = [g.strip() for g in settings.train_hold_out.split(",") if g.strip()]
    extra = {}
    if held:
        from ..garment_transfer import training_garments

        extra = dict(garments=training_garments(dataset, source, targets, None, held), hold_out=held)
    if settings.train_kind == 'GARMENT':
        return dict(dataset_dir=folder, source=source, targets=targets, out=out, kind="garment", **extra)
    return dict(dataset_dir=folder, source=source, targets=targets, epochs=settings.train_epochs,
                latent=settings.train_latent, out=out, **extra)


#: The share of the progress bar that training takes when held-out garments are checked after it.
TRAINING_SHARE = 0.9


def training_call(plan):
    """A function of a progress callback that trains and saves the model of ``plan`` (the garment fit model
    and its placement, in one file, for ``kind="garment"``; else the shared deformation model), then checks
    it on the plan's held-out garments (``model_check.check_model``: the result's ``check``)."""
    from ..garment_transfer import check_after_training, train_from_dataset, train_garment_fit_from_dataset

    options = {k: v for k, v in plan.items() if k not in ("kind", "hold_out")}
    train = train_garment_fit_from_dataset if plan.get("kind") == "garment" else train_from_dataset
    held = plan.get("hold_out")

    def call(progress):
        if not held:
            return train(progress=progress, **options)
        info = train(progress=lambda f, *loss: progress(TRAINING_SHARE * f, *loss), **options)
        info["check"] = check_after_training(
            plan["dataset_dir"], plan["source"], plan["targets"], held, plan["out"],
            progress=lambda f, _stage: progress(TRAINING_SHARE + (1 - TRAINING_SHARE) * f))
        return info

    return call


def drain(steps, pause=0.02):
    """Run a step generator to its end and return its return value."""
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value
        time.sleep(pause)


class GARMENT_TRANSFER_OT_train(ModalSteps, bpy.types.Operator):
    """Train a model of how garments deform between the dataset's bodies and save it as a model
    file (needs PyTorch; Esc cancels without writing a file)"""

    bl_idname = "garment_transfer.train"
    bl_label = "Train Model"
    bl_options = {'REGISTER', 'UNDO'}

    status_text = "Training model"
    cancel_text = "Training cancelled; no model file was written"

    _run = None
    _steps = None
    _plan = None

    @classmethod
    def poll(cls, context):
        settings = getattr(context.scene, "garment_transfer", None)
        if settings is None:
            return False
        if not settings.dataset_path:
            cls.poll_message_set("Choose a dataset folder in the Training section")
            return False
        if not settings.train_output:
            cls.poll_message_set("Choose where to save the model")
            return False
        if not bpy.data.filepath:
            for label, path in (("dataset folder", settings.dataset_path),
                                ("model file", settings.train_output)):
                if path.startswith("//"):
                    # Relative to an unsaved file means relative to wherever Blender was started.
                    cls.poll_message_set(f"The {label} is relative to the .blend file, which is not "
                                         "saved yet: save it, or choose a full path")
                    return False
        if context.mode != 'OBJECT':
            # Training ends by switching the scene's method and model file, and an undo step made
            # in Edit Mode holds the edited mesh only: undo would not take those changes back.
            cls.poll_message_set("Switch to Object Mode first")
            return False
        return True

    def _start(self, context):
        settings = context.scene.garment_transfer
        # The output first (a wrong path is reported even where torch is missing), then torch, then the
        # dataset.
        training_output(settings)
        message = torch_missing_message()
        if message:
            self.report({'ERROR'}, message)
            return False
        self._plan = training_plan(settings)
        self._run = TrainingRun(training_call(self._plan))
        self._steps = self._run.steps()
        return True

    def _finish(self, context, info):
        settings = context.scene.garment_transfer
        settings.train_progress = 100.0
        settings.last_trained_model = self._plan["out"]
        settings.model_path = self._plan["out"]
        settings.method = 'MODEL'
        refresh_found_model(settings, context)
        if self._plan.get("kind") == "garment":
            parts = [f"{name} {part['epochs']} passes, loss {part['final_loss']:.4g}"
                     for name, part in (("field", info.get("field")), ("placement", info.get("placement")))
                     if part]
            what, detail = "Garment fit model", "; ".join(parts)
        else:
            loss = info.get("final_loss")
            loss_text = f", loss {loss:.4g}" if isinstance(loss, (int, float)) else ""
            what, detail = "Model", f"{info.get('epochs')} epochs{loss_text}"
        check = info.get("check")
        # The summary per target (the panel's), not every garment's figures: the scene keeps it.
        kept = ("model", "garments", "targets", "units", "targets_summary", "beats_direct")
        settings.train_check = json.dumps({k: check[k] for k in kept}) if check else ""
        checked = ""
        if check:
            ratios = ", ".join(f"{t} {s['vertex_ratio']:.2f}x" for t, s in check["targets_summary"].items()
                               if s["vertex_ratio"] is not None)
            checked = (f"; on the held-out {', '.join(check['garments'])} its vertex error is below direct "
                       f"transfer's on {len(check['beats_direct'])} of {len(check['targets'])} targets ({ratios})")
        self.report({'INFO'}, f"{what} for {', '.join(self._plan['targets'])} (source "
                              f"{self._plan['source']}) saved to {self._plan['out']}: {detail}, "
                              f"{info.get('seconds', 0.0):.1f} s{checked}")
        return {'FINISHED'}

    def execute(self, context):
        try:
            if not self._start(context):
                return {'CANCELLED'}
            summary = drain(self._steps)
        except Exception as exc:
            return report_failure(self, exc)
        return self._finish(context, summary)

    def _on_progress(self, context, fraction):
        context.scene.garment_transfer.train_progress = 100.0 * fraction
        if self._plan.get("hold_out") and fraction >= TRAINING_SHARE:
            # Training is over and the file written: Esc now stops the check only.
            self.cancel_text = f"Check on the held-out garments cancelled; the model was saved to {self._plan['out']}"


CLASSES = (GARMENT_TRANSFER_OT_train,)
