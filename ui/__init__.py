"""The sidebar tab "Garment" and the settings it edits (``scene.garment_transfer``)."""

import bpy

from . import panels, properties

CLASSES = properties.CLASSES + panels.CLASSES


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    properties.register_settings()


def unregister():
    properties.unregister_settings()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
