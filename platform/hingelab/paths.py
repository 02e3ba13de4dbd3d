"""Locations of the repository's top-level folders.

hingelab is installed editable from its repository (README), so the assets,
analysis and datasets folders sit beside ``platform/``. ``HINGELAB_ASSETS``
overrides the assets folder (a copy elsewhere, a test fixture).
"""

from __future__ import annotations

import os
from pathlib import Path

from hingelab.errors import ConfigError

REPO_ROOT = Path(__file__).resolve().parents[2]
ASSETS_DIR = Path(os.environ.get("HINGELAB_ASSETS", REPO_ROOT / "assets"))
ANALYSIS_DIR = REPO_ROOT / "analysis"
DATASETS_DIR = REPO_ROOT / "datasets"
SCENES_DIR = ASSETS_DIR / "scenes"


def refuse_to_replace_shipped(path: Path, force: bool, flag: str = "--out") -> None:
    """Shipped files under assets/ are replaced only on purpose: raise unless ``force``.

    ``path`` is a file a command is about to write (or a run folder it writes into). A
    new file under assets/ is allowed; replacing one, or writing into a folder that
    holds shipped files, needs ``--force``, because every shipped policy is bound to the
    shipped encoder and scenes.
    """
    path = Path(path).resolve()
    shipped = {ASSETS_DIR.resolve(), (REPO_ROOT / "assets").resolve()}
    if force or not any(path.is_relative_to(root) for root in shipped) or not path.exists():
        return
    raise ConfigError(f"{flag} {path} would replace a shipped file under assets/: write elsewhere, or pass "
                      "--force to replace it on purpose")
