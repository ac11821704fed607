"""Garment Transfer core: design-preserving garment transfer between body shapes.

Plain functions on numpy arrays (and scipy); never imports bpy. Training needs torch;
everything else, transfer included, needs numpy and scipy only.
"""

__version__ = "0.1.0"
