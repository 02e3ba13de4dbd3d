"""Locations of the repository's top-level folders.

hingelab is installed editable from its repository (README), so the assets,
analysis and datasets folders sit beside ``platform/``. ``HINGELAB_ASSETS``
overrides the assets folder (a copy elsewhere, a test fixture).
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]
ASSETS_DIR = Path(os.environ.get("HINGELAB_ASSETS", REPO_ROOT / "assets"))
ANALYSIS_DIR = REPO_ROOT / "analysis"
DATASETS_DIR = REPO_ROOT / "datasets"
SCENES_DIR = ASSETS_DIR / "scenes"
