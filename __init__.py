"""Garment Transfer, a Blender extension: puts a garment made on one body onto a differently shaped
body while keeping its folds.

This file only registers the Blender layer (operators/ and ui/). The geometry is in garment_transfer/,
which never imports bpy. Imports are relative: Blender imports the extension as
``bl_ext.<repository>.garment_transfer``.
"""

from . import operators, ui


def register():
    operators.register()
    ui.register()


def unregister():
    ui.unregister()
    operators.unregister()
