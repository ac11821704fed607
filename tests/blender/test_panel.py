"""The Garment tab: registered in the sidebar, and every property and operator it draws exists.

Panels only draw with a window; here each draw function runs on a recording layout instead."""

from __future__ import annotations

import json
from types import SimpleNamespace

import bpy
import pytest


class RecordingLayout:
    def __init__(self, calls):
        self.calls = calls

    def __getattr__(self, name):
        if name in ("column", "row", "box", "split"):
            return lambda *a, **k: RecordingLayout(self.calls)

        def record(*a, **k):
            self.calls.append((name, a, k))
            return SimpleNamespace()    # an operator button's properties can be set on what it returns
        return record

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)


PANELS = ("VIEW3D_PT_garment_transfer", "VIEW3D_PT_garment_transfer_outfit", "VIEW3D_PT_garment_transfer_motion",
          "VIEW3D_PT_garment_transfer_evaluation",
          "VIEW3D_PT_garment_transfer_training", "VIEW3D_PT_garment_transfer_drape")


@pytest.mark.parametrize("method", ["DIRECT", "MODEL"])
def test_panels_draw_existing_properties_and_operators(extension, method):
    settings = bpy.context.scene.garment_transfer
    settings.method = method
    settings.last_metrics = '{"mdc": 0.02, "penetration_ratio": 0.0}'
    me = bpy.data.meshes.new("g")
    settings.garment = bpy.data.objects.new("g", me)
    names = {p.identifier for p in settings.bl_rna.properties}
    for panel_name in PANELS:
        panel = getattr(bpy.types, panel_name)
        assert panel.bl_category == "Garment" and panel.bl_space_type == 'VIEW_3D'
        calls = []
        panel.draw(SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
        for kind, args, _ in calls:
            if kind in ("prop", "prop_search") and args[0] == settings:
                assert args[1] in names, args[1]
            if kind == "operator":
                module, op = args[0].split(".")
                assert hasattr(getattr(bpy.ops, module), op)
                assert getattr(bpy.types, f"{module.upper()}_OT_{op}", None) is not None, args[0]
    settings.garment = None


def test_training_panel_shows_epochs_and_latent_for_the_shared_kind_only(extension):
    settings = bpy.context.scene.garment_transfer
    assert settings.train_kind == 'GARMENT'       # the garment fit model is the default
    drawn = {}
    for kind in ("SHARED", "GARMENT"):
        settings.train_kind = kind
        calls = []
        bpy.types.VIEW3D_PT_garment_transfer_training.draw(SimpleNamespace(layout=RecordingLayout(calls)),
                                                           bpy.context)
        drawn[kind] = {args[1] for name, args, _ in calls if name == "prop"}
    settings.train_kind = 'SHARED'
    assert {"train_kind", "train_epochs", "train_latent"} <= drawn["SHARED"]
    assert "train_kind" in drawn["GARMENT"] and not {"train_epochs", "train_latent"} & drawn["GARMENT"]


def test_training_panel_says_when_torch_is_missing(extension, monkeypatch):
    monkeypatch.setitem(__import__("sys").modules, "torch", None)
    calls = []
    bpy.types.VIEW3D_PT_garment_transfer_training.draw(
        SimpleNamespace(layout=RecordingLayout(calls)), bpy.context)
    texts = [k.get("text", "") for kind, _, k in calls if kind == "label"]
    assert "pip install torch==2.13.0" in texts


def test_training_panel_shows_the_last_check_of_held_out_garments(extension):
    settings = bpy.context.scene.garment_transfer
    summary = {"model": {"vertex_error_mean": 0.9, "mdc": 0.02, "penetrating_vertices": 0},
               "direct": {"vertex_error_mean": 1.5, "mdc": 0.025, "penetrating_vertices": 0},
               "vertex_ratio": 0.6, "mdc_ratio": 0.8}
    settings.train_check = json.dumps({"garments": ["skirt", "coat"], "targets": ["pear", "heavy"],
                                       "targets_summary": {"pear": summary, "heavy": dict(summary, mdc_ratio=None)}})

    def labels():
        calls = []
        bpy.types.VIEW3D_PT_garment_transfer_training.draw(SimpleNamespace(layout=RecordingLayout(calls)),
                                                           bpy.context)
        assert ("prop", (settings, "train_hold_out"), {}) in calls
        return [k.get("text", "") for kind, _, k in calls if kind == "label"]

    try:
        shown = labels()
        assert "Held out: skirt, coat" in shown
        assert "pear: vertex error 0.60x direct's, MDC 0.80x, 0 inside" in shown
        assert "heavy: vertex error 0.60x direct's, MDC n/a, 0 inside" in shown
        settings.train_check = "{not json"
        assert "The last check could not be read" in labels()
        settings.train_check = ""
        assert not any(t.startswith("Held out") for t in labels())
    finally:
        settings.train_check = ""


def test_operators_have_tooltips_and_undo(extension):
    for op in ("transfer", "evaluate", "train", "drape", "transfer_outfit", "outfit_add", "outfit_remove",
               "outfit_move"):
        cls = getattr(bpy.types, f"GARMENT_TRANSFER_OT_{op}")
        assert {'REGISTER', 'UNDO'} <= set(cls.bl_options)
        assert cls.__doc__ and len(cls.__doc__.split()) > 8
