"""Blender-side lab scripts: run with a Python that has the bpy module (python -m lab make-data | render)."""
