"""Load this checkout as the extension package without installing it (the Blender tests, the lab's Blender
scripts, and ``scripts/batch_transfer.py`` run from a checkout). Not shipped in the extension.

Blender imports an installed extension as ``bl_ext.<repository>.garment_transfer`` and its modules import
the core relatively (``from ..garment_transfer import ...``, the core's public API only). Loaded from a
checkout, the repository root becomes the package ``garment_transfer_ext``, and its core is the
``garment_transfer`` this Python already imports (installed from the same checkout by ``pip install -e .``):
one core per process, one ``MeshError``, one model cache.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "garment_transfer_ext"


def load_extension(name=PACKAGE):
    """Import the repository root as package ``name`` (once) and return it; call ``register()`` on it to add
    the operators and the panel."""
    if name in sys.modules:
        return sys.modules[name]
    import garment_transfer

    spec = importlib.util.spec_from_file_location(name, ROOT / "__init__.py",
                                                  submodule_search_locations=[str(ROOT)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    sys.modules[f"{name}.garment_transfer"] = garment_transfer
    module.garment_transfer = garment_transfer
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name], sys.modules[f"{name}.garment_transfer"]
        raise
    return module
