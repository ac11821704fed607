"""Operators ``bpy.ops.garment_transfer.*``: read objects, call the core, write a new object."""

import bpy

from . import drape, evaluate, models, outfit, rigging, shape_keys, train, transfer

CLASSES = (transfer.CLASSES + models.CLASSES + outfit.CLASSES + shape_keys.CLASSES + train.CLASSES + drape.CLASSES
           + evaluate.CLASSES + rigging.CLASSES)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
