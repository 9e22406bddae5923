"""Files depotbench ships beside its code (``assets/``, installed as the package
``depotbench.assets``), found through ``importlib.resources`` so that an installed wheel
finds them as a checkout does."""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def asset(*parts: str) -> Path:
    """The path of a shipped file, e.g. ``asset("models", "yolox_nano", "yolox_nano.onnx")``.

    A wheel installs its package data as plain files, so the path is a real one that
    OpenCV and ONNX Runtime can open; a zipped install is refused by name rather than
    extracted to a temporary folder behind the caller's back."""
    found = resources.files("depotbench.assets").joinpath(*parts)
    path = Path(str(found))
    if not isinstance(found, Path) and not path.exists():
        raise FileNotFoundError(f"{'/'.join(parts)}: depotbench's assets are not plain files here ({found})")
    return path
